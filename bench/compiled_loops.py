"""Why the ortho's inner loops are C and every other hot loop is numba: what each costs a fresh
process before its first result (docs/conventions.md, "Compiled loops").

`sisa ortho` is a command run on its own, often many times over (one per segment or band set);
the ray caster and the renderer run inside long jobs. The figure that decides is the fixed cost
per process: import, compiler start and cached-kernel load, before one line is mapped. Both sides
run the same loop (the per-line extents of an IGM block, `line_extents` in
postproc/products/_orthokernels.c) on the same block, each in fresh interpreters, alternating;
numba's kernel is compiled and cached once beforehand, as an installed SISA would have it.

    python bench/compiled_loops.py [--runs 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time

NUMBA_SIDE = textwrap.dedent('''
    import time; t0 = time.perf_counter()
    import numpy as np, numba
    @numba.njit(cache=True)
    def line_extents(blk, out):
        for i in range(blk.shape[0]):
            w = s = np.inf; e = n = -np.inf
            for j in range(blk.shape[2]):
                x = blk[i, 0, j]; y = blk[i, 1, j]
                if np.isfinite(x) and np.isfinite(y):
                    w = min(w, x); e = max(e, x); s = min(s, y); n = max(n, y)
            out[i, 0] = w; out[i, 1] = s; out[i, 2] = e; out[i, 3] = n
    blk = np.random.default_rng(0).normal(size=(256, 3, 512)); out = np.empty((256, 4))
    line_extents(blk, out)
    print(time.perf_counter() - t0)
''')

C_SIDE = textwrap.dedent('''
    import time; t0 = time.perf_counter()
    import numpy as np
    from postproc.products.ortho import _line_extents
    blk = np.random.default_rng(0).normal(size=(256, 3, 512)); out = np.empty((256, 4))
    _line_extents(blk, out)
    print(time.perf_counter() - t0)
''')


def _run(code: str, cwd: str, env: dict[str, str]) -> float:
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True,
                          text=True, check=True)
    wall = time.perf_counter() - start
    float(proc.stdout.strip())  # the script's own figure: proves it ran to its result
    return wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=7, help="fresh processes per side (default 7)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=tmp)
        script = os.path.join(tmp, "numba_side.py")
        with open(script, "w", encoding="utf-8") as fh:
            fh.write(NUMBA_SIDE)
        code_numba = (f"import runpy; runpy.run_path({script!r})")
        _run(code_numba, tmp, env)  # compile and cache once
        repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env_c = dict(env, PYTHONPATH=repo + os.pathsep + env.get("PYTHONPATH", ""))
        _run(C_SIDE, tmp, env_c)
        numba_s, c_s, bare_s = [], [], []
        for _ in range(args.runs):
            numba_s.append(_run(code_numba, tmp, env))
            c_s.append(_run(C_SIDE, tmp, env_c))
            bare_s.append(_run("import numpy; print(0)", tmp, env))
    n, c, b = (statistics.median(v) for v in (numba_s, c_s, bare_s))
    load = os.getloadavg()[0]
    print(f"fresh process to first result, median of {args.runs} (load {load:.2f}):")
    print(f"  python + numpy alone      {b:6.3f} s")
    print(f"  numba kernel (cached)     {n:6.3f} s   (+{n - b:.3f} s over numpy alone)")
    print(f"  C kernel through ctypes   {c:6.3f} s   (+{c - b:.3f} s over numpy alone)")
    print(f"  numba's fixed cost per process over C's: {n - c:.3f} s")


if __name__ == "__main__":
    main()
