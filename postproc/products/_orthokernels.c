/* The ortho's inner loops (postproc/ortho.py calls them through ctypes, which releases the
 * GIL, so two windows are made at once on threads).
 *
 * Why C and not numba like the ray caster: `sisa ortho` is a command a user runs on its own,
 * and numba costs every such process 1.5-2 s before the first cell is mapped (importing it,
 * initialising its compiler, loading each cached kernel), a third of the whole run on a
 * 20 000-line segment. These loops are plain arithmetic on contiguous float64/int32 arrays;
 * ortho.py checks types and layout before every call.
 *
 * Arithmetic is IEEE double in the order the docstrings in ortho.py give (no fused
 * multiply-add: built with -ffp-contract=off), so products do not depend on the compiler.
 * Arrays are C-contiguous; sizes are int64. Array names follow ortho.py.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <unistd.h>

typedef int64_t i64;

/* out (lines, 4): west, south, east, north of each line of an IGM block (lines, bands,
 * pixels; bands >= 2) over its pixels with a finite position; NaN where none. */
void line_extents(const double *blk, i64 lines, i64 bands, i64 pixels, double *out)
{
    for (i64 i = 0; i < lines; i++) {
        const double *xs = blk + i * bands * pixels, *ys = xs + pixels;
        double west = INFINITY, south = INFINITY, east = -INFINITY, north = -INFINITY;
        for (i64 j = 0; j < pixels; j++) {
            double x = xs[j], y = ys[j];
            if (isfinite(x) && isfinite(y)) {
                if (x < west) west = x;
                if (x > east) east = x;
                if (y < south) south = y;
                if (y > north) north = y;
            }
        }
        if (west > east) west = south = east = north = NAN;
        double *o = out + 4 * i;
        o[0] = west; o[1] = south; o[2] = east; o[3] = north;
    }
}

/* u, v (lines, pixels): the block's positions in cell units (column and row of the window's
 * cell centres); box (lines, 4): each line's umin, umax, vmin, vmax over its non-NaN values
 * (+inf, -inf where none). */
void to_cells(const double *blk, i64 lines, i64 bands, i64 pixels, double x0, double y0,
              double cell, double *u, double *v, double *box)
{
    for (i64 i = 0; i < lines; i++) {
        const double *xs = blk + i * bands * pixels, *ys = xs + pixels;
        double *ui = u + i * pixels, *vi = v + i * pixels;
        double umin = INFINITY, vmin = INFINITY, umax = -INFINITY, vmax = -INFINITY;
        for (i64 j = 0; j < pixels; j++) {
            double x = (xs[j] - x0) / cell, y = (y0 - ys[j]) / cell;
            ui[j] = x;
            vi[j] = y;
            if (x == x) {
                if (x < umin) umin = x;
                if (x > umax) umax = x;
            }
            if (y == y) {
                if (y < vmin) vmin = y;
                if (y > vmax) vmax = y;
            }
        }
        double *b = box + 4 * i;
        b[0] = umin; b[1] = umax; b[2] = vmin; b[3] = vmax;
    }
}

/* gap (lines, pixels): squared distance from each pixel to the nearest other pixel within
 * +-dl lines and +-dp pixels; inf where none (NaN never counts). */
void gaps(const double *u, const double *v, i64 nl, i64 npx, i64 dl, i64 dp, double *gap)
{
    for (i64 k = 0; k < nl * npx; k++) gap[k] = INFINITY;
    for (i64 i = 0; i < nl; i++) {
        double *gi = gap + i * npx;
        const double *ui = u + i * npx, *vi = v + i * npx;
        i64 a_end = i + dl + 1 < nl ? i + dl + 1 : nl;
        for (i64 a = i; a < a_end; a++) {
            double *ga = gap + a * npx;
            const double *ua = u + a * npx, *va = v + a * npx;
            for (i64 db = -dp; db <= dp; db++) {
                if (a == i && db <= 0) continue;
                i64 j0 = db < 0 ? -db : 0, j1 = db > 0 ? npx - db : npx;
                for (i64 j = j0; j < j1; j++) {
                    double x = ua[j + db] - ui[j], y = va[j + db] - vi[j];
                    double t = x * x + y * y;
                    gi[j] = t < gi[j] ? t : gi[j];
                    ga[j + db] = t < ga[j + db] ? t : ga[j + db];
                }
            }
        }
    }
}

static inline int in_triangle(double ax, double ay, double bx, double by, double cx,
                              double cy, double px, double py)
{
    double area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax);
    if (area == 0.0) return 0;
    double e0 = (bx - ax) * (py - ay) - (by - ay) * (px - ax);
    double e1 = (cx - bx) * (py - by) - (cy - by) * (px - bx);
    double e2 = (ax - cx) * (py - cy) - (ay - cy) * (px - cx);
    double tol = 1e-9 * fabs(area); /* a point on a shared edge is in both: no cracks */
    if (area > 0.0) return e0 >= -tol && e1 >= -tol && e2 >= -tol;
    return e0 <= tol && e1 <= tol && e2 <= tol;
}

/* ceil(x) for 0 < x < 2^53 (truncation is floor there) */
static inline i64 ceil_pos(double x)
{
    i64 i = (i64)x;
    return (double)i < x ? i + 1 : i;
}

static inline double dist2(double x, double y, double px, double py)
{
    double t = (x - px) * (x - px) + (y - py) * (y - py);
    return t == t ? t : INFINITY;
}

/* Move to the nearest pixel within +-dl lines and +-dp pixels while that gets closer. */
static inline void descend(const double *u, const double *v, i64 nl, i64 npx, i64 dl, i64 dp,
                           i64 *li, i64 *pj, double *d, double px, double py)
{
    for (int step = 0; step < 64; step++) {
        i64 bi = *li, bj = *pj;
        double bd = *d;
        i64 a0 = *li - dl > 0 ? *li - dl : 0, a1 = *li + dl + 1 < nl ? *li + dl + 1 : nl;
        i64 b0 = *pj - dp > 0 ? *pj - dp : 0, b1 = *pj + dp + 1 < npx ? *pj + dp + 1 : npx;
        for (i64 a = a0; a < a1; a++) {
            for (i64 b = b0; b < b1; b++) {
                double x = u[a * npx + b], y = v[a * npx + b];
                double t = (x - px) * (x - px) + (y - py) * (y - py);
                if (t < bd) { bi = a; bj = b; bd = t; } /* false for NaN */
            }
        }
        if (bi == *li && bj == *pj) break;
        *li = bi; *pj = bj; *d = bd;
    }
}

static inline double fmin2(double a, double b) { return b < a ? b : a; }
static inline double fmax2(double a, double b) { return b > a ? b : a; }

/* Rasterise quads with first line q0..q1-1 of the block onto the window (rows, cols),
 * keeping each cell's nearest pixel (see ortho._rasterise). */
void rasterise(const double *u, const double *v, const double *box, const double *gap,
               i64 nl, i64 npx, i64 q0, i64 q1, i64 line_base, i64 rows, i64 cols, i64 dl,
               i64 dp, double gap_factor, double *d2, int32_t *line, int32_t *pixel,
               uint8_t *inside)
{
    double last_col = (double)(cols - 1), last_row = (double)(rows - 1);
    i64 q_end = q1 < nl - 1 ? q1 : nl - 1;
    for (i64 i = q0; i < q_end; i++) {
        const double *b0 = box + 4 * i, *b1 = box + 4 * (i + 1);
        if (fmin2(b0[0], b1[0]) > last_col || fmax2(b0[1], b1[1]) < 0
                || fmin2(b0[2], b1[2]) > last_row || fmax2(b0[3], b1[3]) < 0)
            continue; /* the pair of lines misses the window */
        const double *u0 = u + i * npx, *v0 = v + i * npx, *u1 = u0 + npx, *v1 = v0 + npx;
        for (i64 j = 0; j < npx - 1; j++) {
            double ax = u0[j], ay = v0[j], bx = u0[j + 1], by = v0[j + 1];
            double cx = u1[j + 1], cy = v1[j + 1], dx = u1[j], dy = v1[j];
            int oka = ax == ax && ay == ay, okb = bx == bx && by == by;
            int okc = cx == cx && cy == cy, okd = dx == dx && dy == dy;
            int n_ok = oka + okb + okc + okd;
            if (n_ok < 3) continue;
            /* triangles (p, q, r) and (p, r, s); with a corner missing both are one */
            double px = ax, py = ay, qx = bx, qy = by, rx = cx, ry = cy, sx = dx, sy = dy;
            if (n_ok == 3) {
                if (!oka) {
                    px = bx; py = by; qx = cx; qy = cy; rx = dx; ry = dy;
                } else if (!okb) {
                    qx = cx; qy = cy; rx = dx; ry = dy;
                } else if (!okc) {
                    rx = dx; ry = dy;
                }
                sx = rx; sy = ry;
            }
            double umin = fmin2(fmin2(fmin2(px, qx), rx), sx);
            double umax = fmax2(fmax2(fmax2(px, qx), rx), sx);
            double vmin = fmin2(fmin2(fmin2(py, qy), ry), sy);
            double vmax = fmax2(fmax2(fmax2(py, qy), ry), sy);
            if (umax < 0 || vmax < 0 || umin > last_col || vmin > last_row) continue;
            /* ceil and floor of values inside [0, last]: integer casts, no libm calls */
            i64 c_lo = umin > 0 ? ceil_pos(umin) : 0;
            i64 c_hi = umax < last_col ? (i64)umax : cols - 1;
            i64 r_lo = vmin > 0 ? ceil_pos(vmin) : 0;
            i64 r_hi = vmax < last_row ? (i64)vmax : rows - 1;
            for (i64 r = r_lo; r <= r_hi; r++) {
                double fr = (double)r;
                for (i64 c = c_lo; c <= c_hi; c++) {
                    double fc = (double)c;
                    if (!(in_triangle(px, py, qx, qy, rx, ry, fc, fr)
                          || in_triangle(px, py, rx, ry, sx, sy, fc, fr)))
                        continue;
                    double best = dist2(ax, ay, fc, fr), t;
                    i64 li = i, pj = j;
                    t = dist2(bx, by, fc, fr);
                    if (t < best) { best = t; li = i; pj = j + 1; }
                    t = dist2(cx, cy, fc, fr);
                    if (t < best) { best = t; li = i + 1; pj = j + 1; }
                    t = dist2(dx, dy, fc, fr);
                    if (t < best) { best = t; li = i + 1; pj = j; }
                    if (gap[li * npx + pj] <= gap_factor * best) /* else none is nearer */
                        descend(u, v, nl, npx, dl, dp, &li, &pj, &best, fc, fr);
                    i64 k = r * cols + c;
                    if (best < d2[k]) {
                        d2[k] = best;
                        line[k] = (int32_t)(line_base + li);
                        pixel[k] = (int32_t)pj;
                        inside[k] = fabs(u[li * npx + pj] - fc) <= 0.5
                                    && fabs(v[li * npx + pj] - fr) <= 0.5;
                    }
                }
            }
        }
    }
}

/* The first and last line of the valid cells; last = -1 where there is none. */
void line_range(const int32_t *line, const uint8_t *valid, i64 n, i64 *first, i64 *last)
{
    i64 lo = INT64_MAX, hi = -1;
    for (i64 c = 0; c < n; c++) {
        if (valid[c]) {
            if (line[c] < lo) lo = line[c];
            if (line[c] > hi) hi = line[c];
        }
    }
    *first = lo;
    *last = hi;
}

/* spans (chunks, 2): per chunk of chunk_lines image lines from chunk k0 on, the first and
 * last line the valid cells need (first > last where a chunk has none; spans come filled
 * with that). */
void chunk_spans(const int32_t *line, const uint8_t *valid, i64 n, i64 chunk_lines, i64 k0,
                 i64 *spans)
{
    for (i64 c = 0; c < n; c++) {
        if (valid[c]) {
            i64 li = line[c], *s = spans + 2 * (li / chunk_lines - k0);
            if (li < s[0]) s[0] = li;
            if (li > s[1]) s[1] = li;
        }
    }
}

/* out[b * band_stride + c] = block[line[c] - lo, b, pixel[c]] for the valid cells c whose
 * line is in the block (lines, bands, pixels), values of `item` bytes copied as they are. */
void copy_pixels(const uint8_t *block, i64 lo, i64 lines, i64 bands, i64 pixels, i64 item,
                 const int32_t *line, const int32_t *pixel, const uint8_t *valid, i64 n,
                 uint8_t *out, i64 band_stride)
{
    i64 hi = lo + lines;
    for (i64 c = 0; c < n; c++) {
        i64 li = line[c];
        if (!valid[c] || li < lo || li >= hi) continue;
        const uint8_t *src = block + ((li - lo) * bands * pixels + pixel[c]) * item;
        uint8_t *dst = out + c * item;
        switch (item) {
        case 1:
            for (i64 b = 0; b < bands; b++) dst[b * band_stride] = src[b * pixels];
            break;
        case 2:
            for (i64 b = 0; b < bands; b++)
                memcpy(dst + b * band_stride * 2, src + b * pixels * 2, 2);
            break;
        case 4:
            for (i64 b = 0; b < bands; b++)
                memcpy(dst + b * band_stride * 4, src + b * pixels * 4, 4);
            break;
        default:
            for (i64 b = 0; b < bands; b++)
                memcpy(dst + b * band_stride * item, src + b * pixels * item, (size_t)item);
        }
    }
}

/* out (rows, 2, cols): the signed 1-based GLT; figures: filled, infill (as doubles), sum and
 * max of the distances in cell units. */
void glt_values(const int32_t *line, const int32_t *pixel, const uint8_t *inside,
                const double *d2, i64 rows, i64 cols, int32_t *out, double *figures)
{
    i64 filled = 0, infill = 0;
    double total = 0.0, top = 0.0;
    for (i64 r = 0; r < rows; r++) {
        int32_t *o_sample = out + r * 2 * cols, *o_line = o_sample + cols;
        for (i64 c = 0; c < cols; c++) {
            i64 k = r * cols + c;
            if (line[k] < 0) {
                o_sample[c] = 0;
                o_line[c] = 0;
                continue;
            }
            int32_t sign = inside[k] ? 1 : -1;
            o_sample[c] = sign * (pixel[k] + 1);
            o_line[c] = sign * (line[k] + 1);
            filled++;
            infill += !inside[k];
            double d = sqrt(d2[k]);
            total += d;
            top = d > top ? d : top;
        }
    }
    figures[0] = (double)filled;
    figures[1] = (double)infill;
    figures[2] = total;
    figures[3] = top;
}

/* Write a GLT window (rows, 2, cols, little-endian int32) into the GLT file `fd` (BIL, rows of
 * `width` cells, the window's first cell at row0, col0): per row, its two bands from the first
 * to the last non-zero sample, nothing where a row is all zeros (the file is zeros already,
 * and stays sparse there). Returns 0, or the errno of the write that failed. */
int write_glt_rows(int fd, const int32_t *values, i64 rows, i64 cols, i64 width, i64 row0,
                   i64 col0)
{
    for (i64 r = 0; r < rows; r++) {
        const int32_t *s = values + r * 2 * cols;
        i64 a = 0, b = 0;
        for (i64 c = 0; c < cols; c++) {
            if (s[c] != 0) { a = c; b = c + 1; break; }
        }
        for (i64 c = cols - 1; c > a; c--) {
            if (s[c] != 0) { b = c + 1; break; }
        }
        for (i64 band = 0; band < 2 && b > a; band++) {
            const char *src = (const char *)(s + band * cols + a);
            size_t left = (size_t)(b - a) * 4;
            off_t at = (off_t)((((row0 + r) * 2 + band) * width + col0 + a) * 4);
            while (left > 0) {
                ssize_t done = pwrite(fd, src, left, at);
                if (done < 0) {
                    if (errno == EINTR) continue;
                    return errno;
                }
                if (done == 0) return EIO;
                src += done;
                left -= (size_t)done;
                at += done;
            }
        }
    }
    return 0;
}

/* An importable module, so the import system finds this library wherever SISA is
 * installed; its functions are called through ctypes, not through Python objects. */
static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_orthokernels",
    "The ortho's C kernels (postproc/ortho.py calls them through ctypes).", -1, NULL,
};

PyMODINIT_FUNC PyInit__orthokernels(void) { return PyModule_Create(&module); }
