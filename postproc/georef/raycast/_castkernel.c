/* The ray caster's fast path by hand for x86-64 with AVX2 and FMA (cast.py calls it through
 * ctypes, which releases the GIL; it runs the blocks on its own threads, each taking the next
 * block, so the result does not depend on the thread count).
 *
 * Why by hand: numba's loop (kernel.py, the same method) vectorises 4 wide, gathers one lane at
 * a time and floors and clamps per lane, ~110 instructions a ray (docs/benchmarks.md). Here 8
 * rays at once in float32 with int32 DEM indices and hardware gathers of 8-byte corner pairs.
 * The method and its certification are kernel.py's (the package docstring): two Newton steps on
 * the start cell's bilinear patch, accepted when the last step is tiny, stays in the cell and
 * the ray descends; the first-root test per group of lines and chunk of pixels. What differs:
 *   - the models are relative to each ray's start cell (< 1 cell: float32 rounds to 1e-7 cells
 *     there, not 1e-4 as relative to a block): 0.002 mm on the bench scene against 0.035;
 *   - a ray accepted on the previous line starts from its end point there, moved in float32 by
 *     the change of the line's terms; float64 only on a group's first line and for 8 rays any of
 *     which was not accepted (from_previous);
 *   - a ray whose first step left the start cell restarts from that step's end, the float32
 *     models shifted there;
 *   - per pixel, the largest squared rate over the group's lines: the per-ray rates are read
 *     only for a chunk whose bound fails.
 * A ray the fast path does not certify is left with hit = 2 and its line flagged: the safe path
 * (numba, kernel.safe_pass) takes it after this call, so every decision that sends a ray
 * elsewhere is kernel.py's, with its constants (passed in `params`).
 *
 * A line is cast in passes over its rays, each a short loop (many iterations in flight: the
 * gathers' and divisions' latencies overlap) over per-thread scratch rows.
 *
 * Built on any CPU (the AVX2 code is compiled for that target only, function by function);
 * `castkernel_usable()` says whether this CPU runs it, else cast.py takes numba's kernel.
 * Arrays are C-contiguous; sizes int64; names as in kernel.py.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef int64_t i64;
typedef int32_t i32;

/* What every thread reads, and the next block to take. */
struct job {
    const float *dem;
    i64 rows, cols;
    const float *table; /* (levels, tile rows, tile cols): slope maxima, sparse table */
    i64 trows, tcols;
    const i64 *log2;
    const double *coef; /* (n, 30) */
    const double *look9; /* (9, p) */
    i64 p;
    const i64 *starts;
    i64 blocks;
    const double *blk; /* (blocks, 14) */
    double inv_e, inv_n;
    double *oe, *on, *oh;
    uint8_t *ohit; /* 1 certified hit, 2 left to the safe path */
    uint8_t *line_safe; /* lines with a ray left to the safe path */
    i64 *counts; /* (blocks, 4): rays certified here in column 0 */
    i64 group, chunk, tile, cold, prefetch, pf_stride;
    float max_step, root_tol2, margin2;
    i64 next; /* atomic */
};

int castkernel_usable(void)
{
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
    return 0;
#endif
}

/* Largest tile slope over tiles [ty0, ty1] x [tx0, tx1] (two lookups per tile row). */
static float slope_bound(const struct job *J, i32 tx0, i32 tx1, i32 ty0, i32 ty1)
{
    i64 k = J->log2[tx1 - tx0 + 1];
    i64 right = tx1 - ((i64)1 << k) + 1;
    const float *lev = J->table + k * J->trows * J->tcols;
    float worst = 0.0f;
    for (i64 r = ty0; r <= ty1; r++) {
        float a = lev[r * J->tcols + tx0], b = lev[r * J->tcols + right];
        worst = a > worst ? a : worst;
        worst = b > worst ? b : worst;
    }
    return worst;
}

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>

#define AVX __attribute__((target("avx2,fma"), always_inline)) static inline
#define AVXFN __attribute__((target("avx2,fma")))

/* Per-thread scratch: rows of ps elements, the first p8 used (p rounded up to 8; the padding
 * lanes repeat pixel p - 1). */
struct scratch {
    i64 p8, ps; /* ps = p8 + 16: rows 2 or 4 KB apart made loads wait on unrelated stores (4K
                 * aliasing): 15.9 against 13.9 ns a ray */
    double *s; /* each ray's range: the previous line's, then this one's */
    double *look; /* 9 rows: look products */
    float *tiles; /* 4 rows: boxes x0, x1, y0, y1 (cells) of the group's accepted paths */
    float *rmax; /* largest squared rate of the group's accepted rays */
    float *ratio; /* group rows: each ray's squared rate */
    i32 *redo; /* pixels to restart */
    double *s0; /* this line's start ranges */
    float *mod; /* 12 rows: models m0-m8, zr, start cell (x, y) */
    i32 *k; /* start cells' DEM indices */
    float *z; /* 4 rows: their corners; then the patch; then t, x, y, h at the end */
    float *t1; /* the first Newton step */
    i32 *pf; /* DEM cells to prefetch */
    uint8_t *okb; /* acceptance bits of each 8 rays */
    i32 *acc; /* per line of the group: rays with hit 1 */
    float *lookf; /* 9 rows: the look products in float32 */
    float *bc; /* 6 rows: each ray's B and C (x, y, h) in float32, for the next line */
    void *mem;
};

/* Per line: the ray terms' coefficients and the block's constants, broadcast. */
struct line {
    __m256d ae, an, ah, u[9], q[18];
    __m256d fxo, fyo, h0, inv_e, inv_n, lim_x, lim_y, cols;
    __m256 hi, vx0, vx1, vy0, vy1, lim_xf, lim_yf, cell_e, cell_n;
    __m256d ebase, nbase, cell_ed, cell_nd;
    /* from the previous line of the block, in grid cells (x, y) and metres (h), float32:
     * the change of A, and of the rows of u and Q */
    __m256 dA[3], du[9], dq[18];
    __m256i colsi;
};

/* A set of 8 rays: float32 models in t = s - start relative to the start cell, the cell. */
struct models {
    __m256 m[9], zr, cxa, cya;
    __m256i k;
};

/* Half (4 rays) of the float64 set-up: terms B, C from the look products, the position and
 * height at s, the start cell (clamped into the DEM), models rounded to float32. */
AVX void half_models(const struct line *L, __m256d s, const __m256d *l, __m128 *m, __m128 *zr,
                     __m128 *cxa, __m128 *cya, __m128i *k, __m128 *bst)
{
    __m256d be = _mm256_fmadd_pd(L->u[2], l[2], _mm256_fmadd_pd(L->u[1], l[1],
                                 _mm256_mul_pd(L->u[0], l[0])));
    __m256d bn = _mm256_fmadd_pd(L->u[5], l[2], _mm256_fmadd_pd(L->u[4], l[1],
                                 _mm256_mul_pd(L->u[3], l[0])));
    __m256d bh = _mm256_fmadd_pd(L->u[8], l[2], _mm256_fmadd_pd(L->u[7], l[1],
                                 _mm256_mul_pd(L->u[6], l[0])));
    __m256d c[3];
    for (int a = 0; a < 3; a++) {
        const __m256d *q = L->q + 6 * a;
        c[a] = _mm256_fmadd_pd(q[5], l[8], _mm256_fmadd_pd(q[4], l[7], _mm256_fmadd_pd(
            q[3], l[6], _mm256_fmadd_pd(q[2], l[5], _mm256_fmadd_pd(q[1], l[4],
            _mm256_mul_pd(q[0], l[3]))))));
    }
    __m256d two_s = _mm256_add_pd(s, s);
    __m256d x = _mm256_fmadd_pd(_mm256_fmadd_pd(s, _mm256_fmadd_pd(s, c[0], be), L->ae),
                                L->inv_e, L->fxo);
    __m256d y = _mm256_fnmadd_pd(_mm256_fmadd_pd(s, _mm256_fmadd_pd(s, c[1], bn), L->an),
                                 L->inv_n, L->fyo);
    __m256d h = _mm256_add_pd(L->h0, _mm256_fmadd_pd(s, _mm256_fmadd_pd(s, c[2], bh), L->ah));
    /* max(v, 0) gives 0 for a NaN v: the cell stays inside the DEM, the test rejects it */
    __m256d cx = _mm256_min_pd(_mm256_max_pd(_mm256_floor_pd(x), _mm256_setzero_pd()),
                               L->lim_x);
    __m256d cy = _mm256_min_pd(_mm256_max_pd(_mm256_floor_pd(y), _mm256_setzero_pd()),
                               L->lim_y);
    *k = _mm256_cvttpd_epi32(_mm256_fmadd_pd(cy, L->cols, cx));
    *cxa = _mm256_cvtpd_ps(cx);
    *cya = _mm256_cvtpd_ps(cy);
    m[0] = _mm256_cvtpd_ps(_mm256_sub_pd(x, cx));
    m[1] = _mm256_cvtpd_ps(_mm256_mul_pd(_mm256_fmadd_pd(two_s, c[0], be), L->inv_e));
    m[2] = _mm256_cvtpd_ps(_mm256_mul_pd(c[0], L->inv_e));
    m[3] = _mm256_cvtpd_ps(_mm256_sub_pd(y, cy));
    m[4] = _mm256_cvtpd_ps(_mm256_mul_pd(_mm256_fmadd_pd(two_s, c[1], bn),
                                         _mm256_sub_pd(_mm256_setzero_pd(), L->inv_n)));
    m[5] = _mm256_cvtpd_ps(_mm256_mul_pd(c[1], _mm256_sub_pd(_mm256_setzero_pd(), L->inv_n)));
    __m128 z = _mm256_cvtpd_ps(h);
    *zr = z;
    m[6] = _mm256_cvtpd_ps(_mm256_sub_pd(h, _mm256_cvtps_pd(z)));
    m[7] = _mm256_cvtpd_ps(_mm256_fmadd_pd(two_s, c[2], bh));
    m[8] = _mm256_cvtpd_ps(c[2]);
    bst[0] = _mm256_cvtpd_ps(_mm256_mul_pd(be, L->inv_e));
    bst[1] = _mm256_cvtpd_ps(_mm256_mul_pd(bn, _mm256_sub_pd(_mm256_setzero_pd(), L->inv_n)));
    bst[2] = _mm256_cvtpd_ps(bh);
}

#define JOIN(lo, hi) _mm256_set_m128((hi), (lo))

AVX void load_models(const struct scratch *S, i64 j, struct models *M)
{
    for (int r = 0; r < 9; r++) M->m[r] = _mm256_load_ps(S->mod + r * S->ps + j);
    M->zr = _mm256_load_ps(S->mod + 9 * S->ps + j);
    M->cxa = _mm256_load_ps(S->mod + 10 * S->ps + j);
    M->cya = _mm256_load_ps(S->mod + 11 * S->ps + j);
    M->k = _mm256_load_si256((const __m256i *)(S->k + j));
}

/* What the Newton steps give for 8 rays. */
struct newton {
    __m256 t, x, y, h; /* range offset (t1 for a ray to restart), the point in the cell */
    __m256 ok, redo, ratio; /* masks; squared horizontal/vertical rate (0 if not ok) */
    __m256 x0, x1, y0, y1; /* box of the path back up, cells (empty if not ok) */
};

/* The four corners of 8 cells: per row, two gathers of 4 8-byte pairs (half the elements of
 * 4-byte gathers: a gather's cost is per element), lanes (0, 1, 4, 5) and (2, 3, 6, 7) so that
 * one in-lane shuffle leaves each corner in ray order. */
AVX void corners8(const struct job *J, __m256i k, __m256 *z)
{
    const long long *pairs = (const long long *)(const void *)J->dem;
    __m256i order = _mm256_permutevar8x32_epi32(k, _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7));
    __m128i ka = _mm256_castsi256_si128(order), kb = _mm256_extracti128_si256(order, 1);
    __m128i cols = _mm_set1_epi32((i32)J->cols);
    for (int row = 0; row < 2; row++) {
        __m256 a = _mm256_castsi256_ps(_mm256_i32gather_epi64(pairs, ka, 4));
        __m256 b = _mm256_castsi256_ps(_mm256_i32gather_epi64(pairs, kb, 4));
        z[2 * row] = _mm256_shuffle_ps(a, b, 0x88);
        z[2 * row + 1] = _mm256_shuffle_ps(a, b, 0xdd);
        ka = _mm_add_epi32(ka, cols);
        kb = _mm_add_epi32(kb, cols);
    }
}

/* The start cell's patch relative to zr (z00, dx, twist, dy: in place of the corners) and
 * the first Newton step from t = 0 at (m0, m3). */
AVX __m256 step1(const __m256 *m, __m256 zr, __m256 *z)
{
    __m256 z00 = _mm256_sub_ps(z[0], zr), z10 = _mm256_sub_ps(z[2], zr);
    __m256 dxt = _mm256_sub_ps(_mm256_sub_ps(z[1], zr), z00);
    __m256 twist = _mm256_sub_ps(_mm256_sub_ps(_mm256_sub_ps(z[3], zr), z10), dxt);
    __m256 dy0 = _mm256_sub_ps(z10, z00);
    z[0] = z00;
    z[1] = dxt;
    z[2] = twist;
    z[3] = dy0;
    __m256 u = m[0], v = m[3];
    __m256 bx = _mm256_fmadd_ps(v, twist, dxt), by = _mm256_fmadd_ps(u, twist, dy0);
    __m256 surf = _mm256_fmadd_ps(v, by, _mm256_fmadd_ps(u, dxt, z00));
    __m256 rate = _mm256_sub_ps(m[7], _mm256_fmadd_ps(by, m[4], _mm256_mul_ps(bx, m[1])));
    return _mm256_div_ps(_mm256_sub_ps(surf, m[6]), rate);
}

/* kernel.py's `_newton` for 8 rays, after step1 (its patch p and step t1): the second step
 * on the same patch, the acceptance test, the rate and box of the path back up to the block's
 * highest terrain. */
AVX void newton8(const struct job *J, const struct line *L, const struct models *M,
                 const __m256 *p, __m256 t1, struct newton *N)
{
    const __m256 one = _mm256_set1_ps(1.0f), zero = _mm256_setzero_ps();
    const __m256 absmask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
    const __m256 *m = M->m;
    __m256 zr = M->zr;
    __m256 z00 = p[0], dxt = p[1], twist = p[2], dy0 = p[3], bx, by, surf;
    /* step 2, from t1 on the same patch */
    __m256 two_t1 = _mm256_add_ps(t1, t1);
    __m256 xs = _mm256_fmadd_ps(t1, _mm256_fmadd_ps(t1, m[2], m[1]), m[0]);
    __m256 ys = _mm256_fmadd_ps(t1, _mm256_fmadd_ps(t1, m[5], m[4]), m[3]);
    __m256 xd = _mm256_fmadd_ps(two_t1, m[2], m[1]);
    __m256 yd = _mm256_fmadd_ps(two_t1, m[5], m[4]);
    bx = _mm256_fmadd_ps(ys, twist, dxt);
    by = _mm256_fmadd_ps(xs, twist, dy0);
    __m256 gd = _mm256_sub_ps(_mm256_fmadd_ps(two_t1, m[8], m[7]),
                              _mm256_fmadd_ps(by, yd, _mm256_mul_ps(bx, xd)));
    surf = _mm256_fmadd_ps(ys, by, _mm256_fmadd_ps(xs, dxt, z00));
    __m256 g = _mm256_sub_ps(_mm256_fmadd_ps(t1, _mm256_fmadd_ps(t1, m[8], m[7]), m[6]), surf);
    __m256 step = _mm256_div_ps(_mm256_sub_ps(zero, g), gd);
    __m256 t = _mm256_add_ps(t1, step);
    __m256 two_t = _mm256_add_ps(t, t);
    __m256 x = _mm256_fmadd_ps(t, _mm256_fmadd_ps(t, m[2], m[1]), m[0]);
    __m256 y = _mm256_fmadd_ps(t, _mm256_fmadd_ps(t, m[5], m[4]), m[3]);
    __m256 h = _mm256_fmadd_ps(t, _mm256_fmadd_ps(t, m[8], m[7]), m[6]);
    xd = _mm256_fmadd_ps(two_t, m[2], m[1]);
    yd = _mm256_fmadd_ps(two_t, m[5], m[4]);
    __m256 hd = _mm256_fmadd_ps(two_t, m[8], m[7]);
    __m256 gdd = _mm256_sub_ps(_mm256_add_ps(m[8], m[8]), _mm256_mul_ps(_mm256_set1_ps(2.0f),
        _mm256_fmadd_ps(_mm256_mul_ps(twist, xd), yd,
                        _mm256_fmadd_ps(by, m[5], _mm256_mul_ps(bx, m[2])))));
    __m256 ok = _mm256_and_ps(_mm256_and_ps(_mm256_cmp_ps(x, zero, _CMP_GE_OQ),
                                            _mm256_cmp_ps(x, one, _CMP_LE_OQ)),
                              _mm256_and_ps(_mm256_cmp_ps(y, zero, _CMP_GE_OQ),
                                            _mm256_cmp_ps(y, one, _CMP_LE_OQ)));
    __m256 astep = _mm256_and_ps(step, absmask);
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(astep, _mm256_set1_ps(J->max_step), _CMP_LE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(
        _mm256_mul_ps(_mm256_mul_ps(_mm256_and_ps(gdd, absmask), step), step),
        _mm256_mul_ps(_mm256_set1_ps(J->root_tol2), _mm256_and_ps(gd, absmask)), _CMP_LE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(gd, _mm256_set1_ps(-1e-3f), _CMP_LT_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(hd, zero, _CMP_LT_OQ));
    /* the path back up to the block's highest terrain: its box, its tiles */
    __m256 back = _mm256_div_ps(_mm256_sub_ps(_mm256_sub_ps(L->hi, zr), h), hd);
    __m256 xa = _mm256_add_ps(M->cxa, x), ya = _mm256_add_ps(M->cya, y);
    __m256 xb = _mm256_fmadd_ps(xd, back, xa), yb = _mm256_fmadd_ps(yd, back, ya);
    const __m256 pad = _mm256_set1_ps(0.5f); /* cells: the path's curvature */
    __m256 x0 = _mm256_sub_ps(_mm256_min_ps(xa, xb), pad);
    __m256 x1 = _mm256_add_ps(_mm256_max_ps(xa, xb), pad);
    __m256 y0 = _mm256_sub_ps(_mm256_min_ps(ya, yb), pad);
    __m256 y1 = _mm256_add_ps(_mm256_max_ps(ya, yb), pad);
    ok = _mm256_and_ps(ok, _mm256_and_ps(_mm256_cmp_ps(x0, L->vx0, _CMP_GE_OQ),
                                         _mm256_cmp_ps(x1, L->vx1, _CMP_LE_OQ)));
    ok = _mm256_and_ps(ok, _mm256_and_ps(_mm256_cmp_ps(y0, L->vy0, _CMP_GE_OQ),
                                         _mm256_cmp_ps(y1, L->vy1, _CMP_LE_OQ)));
    x1 = _mm256_min_ps(x1, L->lim_xf);
    y1 = _mm256_min_ps(y1, L->lim_yf);
    __m256 hx = _mm256_mul_ps(xd, L->cell_e), hy = _mm256_mul_ps(yd, L->cell_n);
    __m256 ratio = _mm256_div_ps(_mm256_fmadd_ps(hy, hy, _mm256_mul_ps(hx, hx)),
                                 _mm256_mul_ps(hd, hd));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(ratio, _mm256_set1_ps(INFINITY), _CMP_LT_OQ));
    __m256 left = _mm256_or_ps(
        _mm256_or_ps(_mm256_cmp_ps(xs, zero, _CMP_LT_OQ), _mm256_cmp_ps(xs, one, _CMP_GT_OQ)),
        _mm256_or_ps(_mm256_cmp_ps(ys, zero, _CMP_LT_OQ), _mm256_cmp_ps(ys, one, _CMP_GT_OQ)));
    __m256 redo = _mm256_andnot_ps(ok, left);
    const __m256 lo_empty = _mm256_set1_ps(INFINITY), hi_empty = _mm256_set1_ps(-INFINITY);
    N->x0 = _mm256_blendv_ps(lo_empty, x0, ok);
    N->x1 = _mm256_blendv_ps(hi_empty, x1, ok);
    N->y0 = _mm256_blendv_ps(lo_empty, y0, ok);
    N->y1 = _mm256_blendv_ps(hi_empty, y1, ok);
    N->t = _mm256_blendv_ps(t, t1, redo);
    N->x = x;
    N->y = y;
    N->h = h;
    N->ok = ok;
    N->redo = redo;
    N->ratio = _mm256_and_ps(ratio, ok);
}

/* Ground points of 8 rays (float64 from the cell and the point in it), the next start ranges
 * s + t; status 1 (accepted, in front of the camera) or 2. */
AVX void outputs8(const struct line *L, const struct models *M, const struct newton *N,
                  __m256d s0, __m256d s1, double *e, double *n, double *hh, double *snext,
                  int *status_bits)
{
    __m256d ta = _mm256_cvtps_pd(_mm256_castps256_ps128(N->t));
    __m256d tb = _mm256_cvtps_pd(_mm256_extractf128_ps(N->t, 1));
    __m256d sa = _mm256_add_pd(s0, ta), sb = _mm256_add_pd(s1, tb);
    _mm256_storeu_pd(snext, sa);
    _mm256_storeu_pd(snext + 4, sb);
    /* the cell (exact) plus the offset in it (float32, < 1 cell) in float64 */
    __m256d cxa = _mm256_cvtps_pd(_mm256_castps256_ps128(M->cxa));
    __m256d cxb = _mm256_cvtps_pd(_mm256_extractf128_ps(M->cxa, 1));
    __m256d cya = _mm256_cvtps_pd(_mm256_castps256_ps128(M->cya));
    __m256d cyb = _mm256_cvtps_pd(_mm256_extractf128_ps(M->cya, 1));
    __m256d xa = _mm256_add_pd(cxa, _mm256_cvtps_pd(_mm256_castps256_ps128(N->x)));
    __m256d xb = _mm256_add_pd(cxb, _mm256_cvtps_pd(_mm256_extractf128_ps(N->x, 1)));
    __m256d ya = _mm256_add_pd(cya, _mm256_cvtps_pd(_mm256_castps256_ps128(N->y)));
    __m256d yb = _mm256_add_pd(cyb, _mm256_cvtps_pd(_mm256_extractf128_ps(N->y, 1)));
    __m256d ea = _mm256_fmadd_pd(xa, L->cell_ed, L->ebase);
    __m256d eb = _mm256_fmadd_pd(xb, L->cell_ed, L->ebase);
    __m256d na = _mm256_fnmadd_pd(ya, L->cell_nd, L->nbase);
    __m256d nb = _mm256_fnmadd_pd(yb, L->cell_nd, L->nbase);
    __m256d za = _mm256_cvtps_pd(_mm256_castps256_ps128(M->zr));
    __m256d zb = _mm256_cvtps_pd(_mm256_extractf128_ps(M->zr, 1));
    __m256d ha = _mm256_add_pd(za, _mm256_cvtps_pd(_mm256_castps256_ps128(N->h)));
    __m256d hb = _mm256_add_pd(zb, _mm256_cvtps_pd(_mm256_extractf128_ps(N->h, 1)));
    _mm256_storeu_pd(e, ea);
    _mm256_storeu_pd(e + 4, eb);
    _mm256_storeu_pd(n, na);
    _mm256_storeu_pd(n + 4, nb);
    _mm256_storeu_pd(hh, ha);
    _mm256_storeu_pd(hh + 4, hb);
    __m256d ga = _mm256_cmp_pd(sa, _mm256_setzero_pd(), _CMP_GT_OQ);
    __m256d gb = _mm256_cmp_pd(sb, _mm256_setzero_pd(), _CMP_GT_OQ);
    int front = _mm256_movemask_pd(ga) | (_mm256_movemask_pd(gb) << 4);
    *status_bits = _mm256_movemask_ps(N->ok) & front;
}

/* bytes: 1 where the bit is set, else 2 */
static uint64_t status_bytes(int bits)
{
    uint64_t w = 0;
    for (int b = 0; b < 8; b++) w |= (uint64_t)((bits >> b) & 1 ? 1 : 2) << (8 * b);
    return w;
}

static uint32_t STATUS4[16];
static pthread_once_t status_once = PTHREAD_ONCE_INIT;
static void status_init(void)
{
    for (int b = 0; b < 16; b++) STATUS4[b] = (uint32_t)status_bytes(b);
}

AVX void set_line(const struct job *J, i64 i, i64 b, struct line *L)
{
    const double *c = J->coef + i * 30, *k = J->blk + b * 14;
    L->ae = _mm256_set1_pd(c[0]);
    L->an = _mm256_set1_pd(c[1]);
    L->ah = _mm256_set1_pd(c[2]);
    for (int r = 0; r < 9; r++) L->u[r] = _mm256_set1_pd(c[3 + r]);
    for (int r = 0; r < 18; r++) L->q[r] = _mm256_set1_pd(c[12 + r]);
    double fx = k[0], fy = k[1], ox = k[2], oy = k[3];
    L->fxo = _mm256_set1_pd(fx + ox);
    L->fyo = _mm256_set1_pd(fy + oy);
    L->h0 = _mm256_set1_pd(k[10]);
    L->inv_e = _mm256_set1_pd(J->inv_e);
    L->inv_n = _mm256_set1_pd(J->inv_n);
    L->lim_x = _mm256_set1_pd((double)(J->cols - 2));
    L->lim_y = _mm256_set1_pd((double)(J->rows - 2));
    L->lim_xf = _mm256_set1_ps((float)(J->cols - 2));
    L->lim_yf = _mm256_set1_ps((float)(J->rows - 2));
    L->cols = _mm256_set1_pd((double)J->cols);
    L->hi = _mm256_set1_ps((float)k[13]);
    L->vx0 = _mm256_set1_ps((float)(k[4] + ox));
    L->vx1 = _mm256_set1_ps((float)(k[5] + ox));
    L->vy0 = _mm256_set1_ps((float)(k[6] + oy));
    L->vy1 = _mm256_set1_ps((float)(k[7] + oy));
    double cell_e = 1.0 / J->inv_e, cell_n = 1.0 / J->inv_n;
    L->cell_e = _mm256_set1_ps((float)cell_e);
    L->cell_n = _mm256_set1_ps((float)cell_n);
    L->cell_ed = _mm256_set1_pd(cell_e);
    L->cell_nd = _mm256_set1_pd(cell_n);
    L->ebase = _mm256_set1_pd(k[8] - (fx + ox) * cell_e);
    L->nbase = _mm256_set1_pd(k[9] + (fy + oy) * cell_n);
    L->colsi = _mm256_set1_epi32((i32)J->cols);
    if (i > J->starts[b]) {
        const double *was = c - 30, scale[3] = {J->inv_e, -J->inv_n, 1.0};
        for (int a = 0; a < 3; a++) {
            L->dA[a] = _mm256_set1_ps((float)((c[a] - was[a]) * scale[a]));
            for (int r = 0; r < 3; r++)
                L->du[3 * a + r] = _mm256_set1_ps((float)((c[3 + 3 * a + r] - was[3 + 3 * a + r])
                                                          * scale[a]));
            for (int r = 0; r < 6; r++)
                L->dq[6 * a + r] = _mm256_set1_ps((float)((c[12 + 6 * a + r]
                                                           - was[12 + 6 * a + r]) * scale[a]));
        }
    }
}

/* Pass 1 for rays j .. j + 7, each accepted on the previous line: its end point there (the
 * cell, the point in it and its height above zr, left by pass 4 in S->z rows 1-3), moved by
 * the change of the line's terms at that range: x_i(s) = x_(i-1)(s) + dA + s (du.l + s l'dQ l),
 * so float32 suffices (< 1 cell); B and C carried the same way. zr is kept. */
AVX void from_previous(const struct job *J, const struct line *L, struct scratch *S, i64 j)
{
    const i64 ps = S->ps;
    __m256 l[9];
    for (int r = 0; r < 9; r++) l[r] = _mm256_load_ps(S->lookf + r * ps + j);
    __m256d s0 = _mm256_load_pd(S->s + j), s1 = _mm256_load_pd(S->s + j + 4);
    _mm256_store_pd(S->s0 + j, s0);
    _mm256_store_pd(S->s0 + j + 4, s1);
    __m256 s = JOIN(_mm256_cvtpd_ps(s0), _mm256_cvtpd_ps(s1)), two_s = _mm256_add_ps(s, s);
    __m256 val[3];
    for (int a = 0; a < 3; a++) {
        const __m256 *du = L->du + 3 * a, *dq = L->dq + 6 * a;
        __m256 db = _mm256_fmadd_ps(du[2], l[2], _mm256_fmadd_ps(du[1], l[1],
                                    _mm256_mul_ps(du[0], l[0])));
        __m256 dc = _mm256_fmadd_ps(dq[5], l[8], _mm256_fmadd_ps(dq[4], l[7], _mm256_fmadd_ps(
            dq[3], l[6], _mm256_fmadd_ps(dq[2], l[5], _mm256_fmadd_ps(dq[1], l[4],
            _mm256_mul_ps(dq[0], l[3]))))));
        __m256 bb = _mm256_add_ps(_mm256_load_ps(S->bc + a * ps + j), db);
        __m256 cc = _mm256_add_ps(_mm256_load_ps(S->bc + (3 + a) * ps + j), dc);
        _mm256_store_ps(S->bc + a * ps + j, bb);
        _mm256_store_ps(S->bc + (3 + a) * ps + j, cc);
        _mm256_store_ps(S->mod + (1 + 3 * a) * ps + j, _mm256_fmadd_ps(two_s, cc, bb));
        _mm256_store_ps(S->mod + (2 + 3 * a) * ps + j, cc);
        val[a] = _mm256_add_ps(_mm256_load_ps(S->z + (1 + a) * ps + j),
                               _mm256_fmadd_ps(s, _mm256_fmadd_ps(s, dc, db), L->dA[a]));
    }
    __m256 cx = _mm256_load_ps(S->mod + 10 * ps + j), cy = _mm256_load_ps(S->mod + 11 * ps + j);
    __m256 nx = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(cx, _mm256_floor_ps(val[0])),
                                            _mm256_setzero_ps()), L->lim_xf);
    __m256 ny = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(cy, _mm256_floor_ps(val[1])),
                                            _mm256_setzero_ps()), L->lim_yf);
    _mm256_store_ps(S->mod + j, _mm256_sub_ps(val[0], _mm256_sub_ps(nx, cx)));
    _mm256_store_ps(S->mod + 3 * ps + j, _mm256_sub_ps(val[1], _mm256_sub_ps(ny, cy)));
    _mm256_store_ps(S->mod + 6 * ps + j, val[2]);
    _mm256_store_ps(S->mod + 10 * ps + j, nx);
    _mm256_store_ps(S->mod + 11 * ps + j, ny);
    __m256i k = _mm256_add_epi32(_mm256_mullo_epi32(_mm256_cvttps_epi32(ny), L->colsi),
                                 _mm256_cvttps_epi32(nx));
    __m256i was = _mm256_load_si256((const __m256i *)(S->k + j));
    __m256i pf = _mm256_add_epi32(k, _mm256_mullo_epi32(_mm256_sub_epi32(k, was),
                                                        _mm256_set1_epi32((i32)J->prefetch)));
    pf = _mm256_min_epi32(_mm256_max_epi32(pf, _mm256_setzero_si256()),
                          _mm256_set1_epi32((i32)(J->rows * J->cols - J->cols - 2)));
    _mm256_store_si256((__m256i *)(S->pf + j), pf);
    _mm256_store_si256((__m256i *)(S->k + j), k);
}

/* Every ray of line i (gl: its place in the group; cold: start from the guess): set-up,
 * Newton steps, output, certification data; then the rays whose first step left the start
 * cell, restarted from there. */
AVXFN static void cast_line(const struct job *J, struct scratch *S, i64 i, i64 b, i64 gl,
                            int cold)
{
    struct line L;
    set_line(J, i, b, &L);
    const i64 p = J->p, p8 = S->p8, ps = S->ps;
    double *oe = J->oe + i * p, *on = J->on + i * p, *oh = J->oh + i * p;
    uint8_t *hit = J->ohit + i * p;
    double ebuf[8], nbuf[8], hbuf[8];
    __m256d guess;
    {
        const double *c = J->coef + i * 30;
        i64 mid = p / 2;
        double bh = 0.0;
        for (int r = 0; r < 3; r++) bh += c[9 + r] * J->look9[r * p + mid];
        guess = _mm256_set1_pd(-c[2] / bh);
    }
    i64 redo_n = 0;
    int accepted = 0; /* rays with hit 1 */
    float *ratio = S->ratio + gl * ps;
    /* pass 1: each ray's start range, float32 models in t = s - start relative to its start
     * cell, the cell. In float64 (`half_models`) on a group's first line, and for 8 rays any of
     * which was not accepted on the previous line; else from the previous line's end point,
     * moved by the change of the line's terms at the same range (float32: a change of < 1
     * cell, rounded to ~1e-7 cells; a group's 16 lines add up to < 5e-6 m) */
    const __m128i last4 = _mm_set1_epi32((i32)(J->rows * J->cols - J->cols - 2));
    const __m128i ahead4 = _mm_set1_epi32((i32)J->prefetch);
    for (i64 j8 = 0; j8 < p8; j8 += 8) {
        if (gl > 0 && !cold && S->okb[j8 / 8] == 0xff) {
            from_previous(J, &L, S, j8);
            continue;
        }
        for (i64 j = j8; j < j8 + 8; j += 4) {
            __m256d l[9];
            for (int r = 0; r < 9; r++) l[r] = _mm256_load_pd(S->look + r * ps + j);
            __m256d s0 = _mm256_load_pd(S->s + j);
            /* NaN (a miss on the previous line) or a cold start: the guess */
            s0 = cold ? guess : _mm256_blendv_pd(s0, guess, _mm256_cmp_pd(s0, s0, _CMP_UNORD_Q));
            _mm256_store_pd(S->s0 + j, s0);
            __m128 m[9], zr, cxa, cya, bst[3];
            __m128i k;
            half_models(&L, s0, l, m, &zr, &cxa, &cya, &k, bst);
            for (int r = 0; r < 9; r++) _mm_store_ps(S->mod + r * ps + j, m[r]);
            _mm_store_ps(S->mod + 9 * ps + j, zr);
            _mm_store_ps(S->mod + 10 * ps + j, cxa);
            _mm_store_ps(S->mod + 11 * ps + j, cya);
            for (int a = 0; a < 3; a++) {
                _mm_store_ps(S->bc + a * ps + j, bst[a]);
                _mm_store_ps(S->bc + (3 + a) * ps + j, m[2 + 3 * a]);
            }
            /* where this pixel's cell will be PREFETCH lines on (from the previous line's) */
            __m128i was = _mm_load_si128((const __m128i *)(S->k + j));
            __m128i pf = _mm_add_epi32(k, _mm_mullo_epi32(_mm_sub_epi32(k, was), ahead4));
            pf = _mm_min_epi32(_mm_max_epi32(pf, _mm_setzero_si128()), last4);
            _mm_store_si128((__m128i *)(S->pf + j), pf);
            _mm_store_si128((__m128i *)(S->k + j), k);
        }
    }
    /* pass 2: the corners, gathered (a short loop: many gathers in flight) */
    for (i64 j = 0; j < p8; j += 8) {
        __m256 z[4];
        corners8(J, _mm256_load_si256((const __m256i *)(S->k + j)), z);
        for (int r = 0; r < 4; r++) _mm256_store_ps(S->z + r * ps + j, z[r]);
        for (int a = 0; a < 8; a += J->pf_stride) { /* rows are new on most lines */
            _mm_prefetch((const char *)(J->dem + S->pf[j + a]), _MM_HINT_T0);
            _mm_prefetch((const char *)(J->dem + S->pf[j + a] + J->cols), _MM_HINT_T0);
        }
    }
    /* pass 3: the first Newton step (short: several in flight, their divisions overlap) */
    for (i64 j = 0; j < p8; j += 8) {
        __m256 m[9], z[4];
        for (int r = 0; r < 9; r++) m[r] = _mm256_load_ps(S->mod + r * ps + j);
        for (int r = 0; r < 4; r++) z[r] = _mm256_load_ps(S->z + r * ps + j);
        __m256 t1 = step1(m, _mm256_load_ps(S->mod + 9 * ps + j), z);
        for (int r = 0; r < 4; r++) _mm256_store_ps(S->z + r * ps + j, z[r]);
        _mm256_store_ps(S->t1 + j, t1);
    }
    /* pass 4: the second step, outputs, certification data */
    for (i64 j = 0; j < p8; j += 8) {
        struct models M;
        load_models(S, j, &M);
        __m256 z[4];
        for (int r = 0; r < 4; r++) z[r] = _mm256_load_ps(S->z + r * ps + j);
        struct newton N;
        newton8(J, &L, &M, z, _mm256_load_ps(S->t1 + j), &N);
        /* for pass 5, in place of the corners */
        _mm256_store_ps(S->z + j, N.t);
        _mm256_store_ps(S->z + ps + j, N.x);
        _mm256_store_ps(S->z + 2 * ps + j, N.y);
        _mm256_store_ps(S->z + 3 * ps + j, N.h);
        S->okb[j / 8] = (uint8_t)_mm256_movemask_ps(N.ok);
        _mm256_store_ps(ratio + j, N.ratio);
        __m256 rm = _mm256_load_ps(S->rmax + j);
        _mm256_store_ps(S->rmax + j, gl == 0 ? N.ratio : _mm256_max_ps(rm, N.ratio));
        float *tl = S->tiles;
        __m256 *a = (__m256 *)(tl + j), *c = (__m256 *)(tl + ps + j);
        __m256 *d = (__m256 *)(tl + 2 * ps + j), *e = (__m256 *)(tl + 3 * ps + j);
        if (gl == 0) {
            *a = N.x0;
            *c = N.x1;
            *d = N.y0;
            *e = N.y1;
        } else {
            *a = _mm256_min_ps(*a, N.x0);
            *c = _mm256_max_ps(*c, N.x1);
            *d = _mm256_min_ps(*d, N.y0);
            *e = _mm256_max_ps(*e, N.y1);
        }
        int rb = _mm256_movemask_ps(N.redo);
        if (j + 8 > p) rb &= (1 << (p - j)) - 1;
        while (rb) {
            int lane = __builtin_ctz(rb);
            rb &= rb - 1;
            S->redo[redo_n++] = (i32)(j + lane);
        }
    }
    /* pass 5: ground points in float64 (the cell, exact, plus the float32 point in it), the
     * next line's start ranges, hit 1 (accepted, in front of the camera) or 2 */
    for (i64 j = 0; j < p8; j += 4) {
        __m256d s0 = _mm256_load_pd(S->s0 + j);
        __m256d sn = _mm256_add_pd(s0, _mm256_cvtps_pd(_mm_load_ps(S->z + j)));
        _mm256_store_pd(S->s + j, sn);
        __m256d x = _mm256_add_pd(_mm256_cvtps_pd(_mm_load_ps(S->mod + 10 * ps + j)),
                                  _mm256_cvtps_pd(_mm_load_ps(S->z + ps + j)));
        __m256d y = _mm256_add_pd(_mm256_cvtps_pd(_mm_load_ps(S->mod + 11 * ps + j)),
                                  _mm256_cvtps_pd(_mm_load_ps(S->z + 2 * ps + j)));
        __m256d h = _mm256_add_pd(_mm256_cvtps_pd(_mm_load_ps(S->mod + 9 * ps + j)),
                                  _mm256_cvtps_pd(_mm_load_ps(S->z + 3 * ps + j)));
        __m256d e = _mm256_fmadd_pd(x, L.cell_ed, L.ebase);
        __m256d nn = _mm256_fnmadd_pd(y, L.cell_nd, L.nbase);
        int front = _mm256_movemask_pd(_mm256_cmp_pd(sn, _mm256_setzero_pd(), _CMP_GT_OQ));
        int bits4 = (S->okb[j / 8] >> (j & 4)) & front;
        uint32_t hb = STATUS4[bits4];
        int real = j + 4 <= p ? 15 : j < p ? (1 << (p - j)) - 1 : 0; /* lanes < p */
        accepted += __builtin_popcount((unsigned)(bits4 & real));
        if (j + 4 <= p) {
            _mm256_storeu_pd(oe + j, e);
            _mm256_storeu_pd(on + j, nn);
            _mm256_storeu_pd(oh + j, h);
            memcpy(hit + j, &hb, 4);
        } else if (j < p) {
            _mm256_storeu_pd(ebuf, e);
            _mm256_storeu_pd(nbuf, nn);
            _mm256_storeu_pd(hbuf, h);
            memcpy(oe + j, ebuf, (size_t)(p - j) * 8);
            memcpy(on + j, nbuf, (size_t)(p - j) * 8);
            memcpy(oh + j, hbuf, (size_t)(p - j) * 8);
            memcpy(hit + j, &hb, (size_t)(p - j));
        }
    }
    /* restarts, 8 at a time, from the start plus the first step (s, left by pass 5) on the
     * cell reached: the float32 models moved to t1 (a shift of their origin: what the first
     * step computed; ~1e-7 cells), no float64 set-up */
    for (i64 r0 = 0; r0 < redo_n; r0 += 8) {
        i32 idx[8] __attribute__((aligned(32)));
        for (int a = 0; a < 8; a++) idx[a] = S->redo[r0 + a < redo_n ? r0 + a : redo_n - 1];
        __m256i at = _mm256_load_si256((const __m256i *)idx);
        struct models M;
        __m256 m[9];
        for (int r = 0; r < 9; r++) m[r] = _mm256_i32gather_ps(S->mod + r * ps, at, 4);
        M.zr = _mm256_i32gather_ps(S->mod + 9 * ps, at, 4);
        __m256 cx = _mm256_i32gather_ps(S->mod + 10 * ps, at, 4);
        __m256 cy = _mm256_i32gather_ps(S->mod + 11 * ps, at, 4);
        __m256 tr = _mm256_i32gather_ps(S->t1, at, 4), two_t1 = _mm256_add_ps(tr, tr);
        __m256 xs = _mm256_fmadd_ps(tr, _mm256_fmadd_ps(tr, m[2], m[1]), m[0]);
        __m256 ys = _mm256_fmadd_ps(tr, _mm256_fmadd_ps(tr, m[5], m[4]), m[3]);
        __m256 nx = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(cx, _mm256_floor_ps(xs)),
                                                _mm256_setzero_ps()), L.lim_xf);
        __m256 ny = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(cy, _mm256_floor_ps(ys)),
                                                _mm256_setzero_ps()), L.lim_yf);
        M.m[0] = _mm256_sub_ps(xs, _mm256_sub_ps(nx, cx));
        M.m[3] = _mm256_sub_ps(ys, _mm256_sub_ps(ny, cy));
        M.m[6] = _mm256_fmadd_ps(tr, _mm256_fmadd_ps(tr, m[8], m[7]), m[6]);
        for (int a = 0; a < 3; a++) {
            M.m[1 + 3 * a] = _mm256_fmadd_ps(two_t1, m[2 + 3 * a], m[1 + 3 * a]);
            M.m[2 + 3 * a] = m[2 + 3 * a];
        }
        M.cxa = nx;
        M.cya = ny;
        M.k = _mm256_add_epi32(_mm256_mullo_epi32(_mm256_cvttps_epi32(ny), L.colsi),
                               _mm256_cvttps_epi32(nx));
        __m256d s0 = _mm256_i32gather_pd(S->s, _mm256_castsi256_si128(at), 8);
        __m256d s1 = _mm256_i32gather_pd(S->s, _mm256_extracti128_si256(at, 1), 8);
        __m256 z[4];
        corners8(J, M.k, z);
        __m256 first = step1(M.m, M.zr, z);
        struct newton N;
        newton8(J, &L, &M, z, first, &N);
        double snext[8];
        int bits;
        outputs8(&L, &M, &N, s0, s1, ebuf, nbuf, hbuf, snext, &bits);
        float rt[8], ex[8], ey[8], eh[8], ncx[8], ncy[8];
        _mm256_storeu_ps(ex, N.x);
        _mm256_storeu_ps(ey, N.y);
        _mm256_storeu_ps(eh, N.h);
        _mm256_storeu_ps(ncx, M.cxa);
        _mm256_storeu_ps(ncy, M.cya);
        int okbits = _mm256_movemask_ps(N.ok);
        float t0[8], t1[8], t2[8], t3[8];
        _mm256_storeu_ps(rt, N.ratio);
        _mm256_storeu_ps(t0, N.x0);
        _mm256_storeu_ps(t1, N.x1);
        _mm256_storeu_ps(t2, N.y0);
        _mm256_storeu_ps(t3, N.y1);
        int lanes = redo_n - r0 < 8 ? (int)(redo_n - r0) : 8;
        for (int a = 0; a < lanes; a++) {
            i64 j = idx[a];
            oe[j] = ebuf[a];
            on[j] = nbuf[a];
            oh[j] = hbuf[a];
            S->s[j] = snext[a];
            hit[j] = (bits >> a) & 1 ? 1 : 2;
            accepted += (bits >> a) & 1;
            ratio[j] = rt[a];
            /* the first try added nothing to the group's bounds (it was not accepted) */
            S->rmax[j] = rt[a] > S->rmax[j] ? rt[a] : S->rmax[j];
            float *tl = S->tiles;
            tl[j] = t0[a] < tl[j] ? t0[a] : tl[j];
            tl[ps + j] = t1[a] > tl[ps + j] ? t1[a] : tl[ps + j];
            tl[2 * ps + j] = t2[a] < tl[2 * ps + j] ? t2[a] : tl[2 * ps + j];
            tl[3 * ps + j] = t3[a] > tl[3 * ps + j] ? t3[a] : tl[3 * ps + j];
            if ((okbits >> a) & 1) { /* accepted now: the next line can start from here */
                S->z[ps + j] = ex[a];
                S->z[2 * ps + j] = ey[a];
                S->z[3 * ps + j] = eh[a];
                S->mod[10 * ps + j] = ncx[a];
                S->mod[11 * ps + j] = ncy[a];
                S->okb[j / 8] |= (uint8_t)(1 << (j % 8));
            }
        }
    }
    S->acc[gl] = accepted;
}

/* First-root test for the group's lines i0 .. i0 + lines - 1, chunk by chunk: the steepest
 * slope under the accepted rays' paths; where the group's largest rate of a chunk times it
 * stays below the margin every accepted ray passes, else ray by ray. Rays that fail are left
 * to the safe path (status 2, line flagged). */
static void certify(const struct job *J, struct scratch *S, i64 i0, i64 lines, i64 b)
{
    const i64 p = J->p, ps = S->ps;
    for (i64 c0 = 0; c0 < p; c0 += J->chunk) {
        i64 c1 = c0 + J->chunk < p ? c0 + J->chunk : p;
        float fx0 = INFINITY, fy0 = INFINITY, fx1 = -INFINITY, fy1 = -INFINITY;
        float worst = 0.0f;
        const float *tl = S->tiles;
        for (i64 j = c0; j < c1; j++) {
            fx0 = tl[j] < fx0 ? tl[j] : fx0;
            fx1 = tl[ps + j] > fx1 ? tl[ps + j] : fx1;
            fy0 = tl[2 * ps + j] < fy0 ? tl[2 * ps + j] : fy0;
            fy1 = tl[3 * ps + j] > fy1 ? tl[3 * ps + j] : fy1;
            worst = S->rmax[j] > worst ? S->rmax[j] : worst;
        }
        float limit = 0.0f; /* no accepted ray: nothing passes */
        if (fx0 <= fx1 && fy0 <= fy1) { /* cells >= 0 here: truncation is the floor */
            float inv_tile = 1.0f / (float)J->tile;
            float sl = slope_bound(J, (i32)(fx0 * inv_tile), (i32)(fx1 * inv_tile),
                                   (i32)(fy0 * inv_tile), (i32)(fy1 * inv_tile));
            limit = (float)((double)J->margin2 / ((double)sl * (double)sl));
        }
        if (worst < limit) continue; /* every accepted ray of the chunk passes */
        for (i64 g = 0; g < lines; g++) {
            uint8_t *hit = J->ohit + (i0 + g) * p;
            const float *ratio = S->ratio + g * ps;
            for (i64 j = c0; j < c1; j++)
                if (hit[j] == 1 && !(ratio[j] < limit)) {
                    hit[j] = 2;
                    S->acc[g]--;
                }
        }
    }
    i64 passed = 0;
    for (i64 g = 0; g < lines; g++) {
        passed += S->acc[g];
        J->line_safe[i0 + g] = S->acc[g] != p;
    }
    J->counts[b * 4] += passed;
}

static void *worker(void *arg)
{
    struct job *J = arg;
    i64 p8 = (J->p + 7) & ~(i64)7, ps = p8 + 16;
    /* rows of ps elements (4 or 8 bytes): s, look 9, tiles 4, rmax, ratio group, redo, s0,
     * mod 12, k, z 4, t1, pf, lookf 9, bc 6, okb (bytes) */
    size_t rows4 = 4 + 1 + (size_t)J->group + 1 + 12 + 1 + 4 + 1 + 1 + 9 + 6 + 1 + 1;
    size_t rows8 = 1 + 9 + 1;
    size_t bytes = (size_t)ps * (4 * rows4 + 8 * rows8);
    struct scratch S;
    S.mem = aligned_alloc(64, (bytes + 63) & ~(size_t)63);
    if (S.mem == NULL) {
        return NULL;
    }
    memset(S.mem, 0, bytes);
    S.p8 = p8;
    S.ps = ps;
    char *at = S.mem;
#define CARVE(field, type, rows) \
    S.field = (type *)(void *)at; \
    at += (size_t)(rows) * ps * sizeof(type);
    CARVE(s, double, 1)
    CARVE(look, double, 9)
    CARVE(s0, double, 1)
    CARVE(tiles, float, 4)
    CARVE(rmax, float, 1)
    CARVE(ratio, float, J->group)
    CARVE(redo, i32, 1)
    CARVE(mod, float, 12)
    CARVE(k, i32, 1)
    CARVE(z, float, 4)
    CARVE(t1, float, 1)
    CARVE(pf, i32, 1)
    CARVE(lookf, float, 9)
    CARVE(bc, float, 6)
    CARVE(okb, uint8_t, 4)
    CARVE(acc, i32, 1)
#undef CARVE
    for (int r = 0; r < 9; r++)
        for (i64 j = 0; j < p8; j++) {
            S.look[r * ps + j] = J->look9[r * J->p + (j < J->p ? j : J->p - 1)];
            S.lookf[r * ps + j] = (float)S.look[r * ps + j];
        }
    for (;;) {
        i64 b = __atomic_fetch_add(&J->next, 1, __ATOMIC_RELAXED);
        if (b >= J->blocks) break;
        i64 i0 = J->starts[b];
        for (i64 i = J->starts[b]; i < J->starts[b + 1]; i++) {
            i64 gl = i - i0;
            i64 rounds = i == J->starts[b] ? J->cold : 1;
            for (i64 r = 0; r < rounds; r++) cast_line(J, &S, i, b, gl, rounds > 1 && r == 0);
            if (gl == J->group - 1 || i == J->starts[b + 1] - 1) {
                certify(J, &S, i0, gl + 1, b);
                i0 = i + 1;
            }
        }
    }
    free(S.mem);
    return NULL;
}

/* The fast path for every block on `threads` threads (each takes the next block); returns 0,
 * or -1 if no thread had memory for its scratch (the outputs are then unfinished). */
int cast_fast(const float *dem, i64 rows, i64 cols, const float *table, i64 trows, i64 tcols,
              const i64 *log2, const double *coef, const double *look9, i64 p,
              const i64 *starts, i64 blocks, const double *blk, const double *consts,
              double *oe, double *on, double *oh, uint8_t *ohit, uint8_t *line_safe,
              i64 *counts, const double *params, i64 threads)
{
    pthread_once(&status_once, status_init);
    struct job J = {
        .dem = dem, .rows = rows, .cols = cols, .table = table, .trows = trows,
        .tcols = tcols, .log2 = log2, .coef = coef, .look9 = look9, .p = p, .starts = starts,
        .blocks = blocks, .blk = blk, .inv_e = consts[0], .inv_n = consts[1], .oe = oe,
        .on = on, .oh = oh, .ohit = ohit, .line_safe = line_safe, .counts = counts,
        .group = (i64)params[0], .chunk = (i64)params[1], .tile = (i64)params[2],
        .cold = (i64)params[3], .root_tol2 = (float)(2.0 * params[4]),
        .max_step = (float)params[5], .margin2 = (float)(params[6] * params[6]),
        .prefetch = (i64)params[7], .pf_stride = (i64)params[8], .next = 0,
    };
    if (threads < 1) threads = 1;
    if (threads > 64) threads = 64;
    pthread_t tid[64];
    i64 started = 0;
    for (i64 t = 1; t < threads; t++) {
        if (pthread_create(&tid[started], NULL, worker, &J) != 0) break;
        started++;
    }
    worker(&J);
    for (i64 t = 0; t < started; t++) pthread_join(tid[t], NULL);
    /* a thread without its scratch took no block; the others took them all, unless none had */
    return J.next >= J.blocks ? 0 : -1;
}

#else /* no AVX2 build: castkernel_usable() is 0 and this is never called */
int cast_fast(void) { return -1; }
#endif

/* An importable module, so the import system finds this library wherever SISA is
 * installed; its functions are called through ctypes, not through Python objects. */
static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_castkernel",
    "The ray caster's AVX2 fast path (postproc/georef/raycast/cast.py calls it through ctypes).",
    -1, NULL,
};

PyMODINIT_FUNC PyInit__castkernel(void) { return PyModule_Create(&module); }
