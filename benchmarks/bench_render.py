"""Benchmark: speed and accuracy of the IQ rendering of moved scatterers (render_iq).

The paper's volume (128 x 48 x 204 voxels of 0.5 x 0.5 x 0.3 mm, `paper_grid`), default
transducer, scatterers from `random_scatterers` at 5 per resolution cell over the grid's
box plus a margin (4.8 mm, as `SpeckleScene` uses), complex amplitudes. Times the
spectral path (``method="nufft"``, the default) and the exact 3-sigma sum, each the minimum
of `--repeats` runs, and the exact sum with ``truncate_sigmas=--reference-sigmas`` once as
the untruncated reference. Errors are relative to the RMS of the reference volume.

    OMP_NUM_THREADS=1 python benchmarks/bench_render.py [--repeats 3] [--reference-sigmas 7]
        [--no-reference]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from liverinv.imaging.grid import paper_grid
from liverinv.imaging.speckle import Transducer, random_scatterers, render_iq


def scatterers(grid, tr, per_cell, margin_m, seed):
    """Scatterers over the grid's box plus `margin_m`, with complex amplitudes."""
    rng = np.random.default_rng(seed)
    lo = np.asarray(grid.origin_m) - margin_m
    hi = grid.to_m(np.asarray(grid.shape) - 1) + margin_m
    pos, amp = random_scatterers(rng, lo, hi, per_cell, tr)
    return pos, amp * np.exp(2j * np.pi * rng.random(len(amp)))


def timed(fn, repeats):
    """(minimum seconds over `repeats` calls, last result)."""
    best, out = np.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def errors(a, ref):
    """(max, RMS) of |a - ref| relative to the RMS of `ref`."""
    d = np.abs(a.astype(complex) - ref)
    rms = np.sqrt(np.mean(np.abs(ref) ** 2))
    return d.max() / rms, np.sqrt(np.mean(d ** 2)) / rms


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--per-cell", type=float, default=5.0)
    ap.add_argument("--margin-mm", type=float, default=4.8)
    ap.add_argument("--reference-sigmas", type=float, default=7.0)
    ap.add_argument("--no-reference", action="store_true",
                    help="skip the untruncated exact sum (about 100 s)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)

    grid, tr = paper_grid(), Transducer()
    pos, amp = scatterers(grid, tr, args.per_cell, args.margin_mm * 1e-3, args.seed)
    print(f"grid {grid.shape}, spacing {tuple(1e3 * s for s in grid.spacing_m)} mm, "
          f"{len(pos)} scatterers")
    t_fast, fast = timed(lambda: render_iq(grid, pos, amp, tr), args.repeats)
    t_ex3, ex3 = timed(lambda: render_iq(grid, pos, amp, tr, method="exact"), args.repeats)
    rows = [("nufft (untruncated)", t_fast), (f"exact, {tr.truncate_sigmas:g} sigmas", t_ex3)]
    ref = None
    if not args.no_reference:
        untr = Transducer(truncate_sigmas=args.reference_sigmas)
        t_ref, ref = timed(lambda: render_iq(grid, pos, amp, untr, method="exact"), 1)
        rows.append((f"exact, {args.reference_sigmas:g} sigmas (1 run)", t_ref))
    print(f"\n{'method':32s} {'s / volume':>10s}")
    for name, t in rows:
        print(f"{name:32s} {t:10.3f}")
    print(f"speed-up nufft vs exact 3 sigmas: {t_ex3 / t_fast:.1f}x\n")
    print(f"{'difference (relative to RMS)':40s} {'max':>9s} {'RMS':>9s}")
    pairs = [("nufft - exact 3 sigmas", fast, ex3)]
    if ref is not None:
        pairs = [("nufft - exact untruncated", fast, ref),
                 ("exact 3 sigmas - exact untruncated", ex3, ref)] + pairs
    for name, a, b in pairs:
        mx, rm = errors(a, b.astype(complex))
        print(f"{name:40s} {mx:9.2e} {rm:9.2e}")


if __name__ == "__main__":
    main()
