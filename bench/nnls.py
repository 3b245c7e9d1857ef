"""Benchmark: whole-take non-negative keyshape weights (Chuang Eq. 3.1/3.2) against SciPy per frame.

``faceretarget.numerics.solve_nnls`` on synthetic problems of the P1 sizes (68 landmarks x 3 =
204 features, 40 and 83 keyshapes, a 2,028-frame take) against ``scipy.optimize.nnls`` called for
every frame, both timed in this process (best of ``--repeat`` interleaved runs, single-threaded
BLAS recommended: ``OPENBLAS_NUM_THREADS=1``).  Reports the speedup and the largest absolute
difference of the weights.  The keyshapes are smooth, localised, correlated marker displacements
(several keys per facial region moving in similar directions, condition numbers in the hundreds
like real landmark keyshapes); the take has smooth, often-zero weight curves plus capture noise.

The optional terms (upper bound, temporal smoothing) are timed too, for information.

A second family, ``rom-keys``, has keyshapes chosen among the frames of a range-of-motion take
(PCA extrema, like P1's ``rom-K`` sets; with N = 83 the keys are linearly dependent, like
``combined84``): strongly correlated keys and sparse weights, the hard case for batching (solved by
Lawson-Hanson).  Where the keys are dependent the weights are not unique and the fit is compared
instead.

Usage::

    python bench/nnls.py [--quick] [--repeat 3] [--json]

With ``--json`` the last line of stdout is one JSON object with ``nnls_speedup`` (the smallest
speedup over the ``keyshapes`` problem sizes), ``nnls_max_abs_diff`` (their largest difference),
``nnls_speedup_rom_keys`` and every case in ``nnls_cases``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.optimize import nnls

from faceretarget.datasets import keyshape_problem, rom_problem
from faceretarget.numerics import solve_nnls

SIZES = ((204, 40, 2028), (204, 83, 2028))


def _best(fn, repeat: int):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="500-frame takes, one repeat")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each solver (best is kept)")
    ap.add_argument("--json", action="store_true", help="print a JSON summary as the last line")
    args = ap.parse_args(argv)
    repeat = 1 if args.quick else max(1, args.repeat)
    # one-time costs (loading the compiled kernel when numba is installed) are not per-take costs
    t0 = time.perf_counter()
    solve_nnls(*keyshape_problem(30, 4, 4, 0))
    print(f"warm-up (imports, compiled-kernel load) {time.perf_counter() - t0:.2f} s")
    cases = []
    for kind, make in (("keyshapes", keyshape_problem), ("rom-keys", rom_problem)):
        for i, (D, N, T) in enumerate(SIZES):
            T = 500 if args.quick else T
            K, F = make(D, N, T, seed=i)
            t_ref = t_ours = np.inf
            for _ in range(repeat):                    # interleaved: both see the same machine state
                t, R = _best(lambda K=K, F=F: np.array([nnls(K, f)[0] for f in F]), 1)
                t_ref = min(t_ref, t)
                t, W = _best(lambda K=K, F=F: solve_nnls(K, F), 1)
                t_ours = min(t_ours, t)
            diff = float(np.abs(W - R).max())
            # where the keys are dependent the weights are not unique: compare the fit as well
            res = float(np.max(np.linalg.norm(W @ K.T - F, axis=1) - np.linalg.norm(R @ K.T - F, axis=1)))
            t_ub, _ = _best(lambda K=K, F=F: solve_nnls(K, F, upper=1.0), 1)
            lam = float(np.linalg.eigvalsh(K.T @ K)[-1])
            t_sm, _ = _best(lambda K=K, F=F, lam=lam: solve_nnls(K, F, upper=1.0, smooth=0.01 * lam), 1)
            rank = int(np.linalg.matrix_rank(K))
            case = {"kind": kind, "D": D, "N": N, "T": T, "rank_K": rank, "cond_K": float(np.linalg.cond(K)),
                    "zero_weight_share": float((R == 0).mean()),
                    "scipy_per_frame_s": t_ref, "solve_nnls_s": t_ours, "speedup": t_ref / t_ours,
                    "max_abs_diff": diff, "max_residual_excess": res, "upper_s": t_ub, "smooth_upper_s": t_sm}
            cases.append(case)
            print(f"{kind:9s} D={D} N={N} T={T} (rank {rank}, cond K {case['cond_K']:.2g}, "
                  f"{100 * case['zero_weight_share']:.0f} % zero weights): "
                  f"scipy per frame {t_ref * 1e3:.1f} ms, "
                  f"solve_nnls {t_ours * 1e3:.1f} ms, speedup {t_ref / t_ours:.1f}x, max |diff| {diff:.2e}"
                  f"{'' if rank == N else f' (not unique; residual excess {res:.1e})'}; "
                  f"with upper=1 {t_ub * 1e3:.1f} ms, + smooth {t_sm * 1e3:.0f} ms")
    main_cases = [c for c in cases if c["kind"] == "keyshapes"]
    summary = {"nnls_speedup": min(c["speedup"] for c in main_cases),
               "nnls_max_abs_diff": max(c["max_abs_diff"] for c in main_cases),
               "nnls_speedup_rom_keys": min(c["speedup"] for c in cases if c["kind"] == "rom-keys"),
               "nnls_cases": cases}
    print(f"speedup (worst of the keyshape cases) {summary['nnls_speedup']:.1f}x, "
          f"max |diff| {summary['nnls_max_abs_diff']:.2e}; "
          f"rom-keys cases {summary['nnls_speedup_rom_keys']:.1f}x")
    if args.json:
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
