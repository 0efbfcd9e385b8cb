"""Benchmark: nodal Lucas-Kanade tracking accuracy and speed on synthetic 3D ultrasound.

The truth is a smooth indentation-like motion (liverinv.imaging.analytic) on the coarse
benchmark mesh, 100 volumes over a load/unload cycle, scaled so the largest motion is about
0.3 voxel per frame; or a forward run given with --truth (synthesize --truth-out). Four
data sets: warped reference volume and moved scatterers, each with and without noise.
For each: time to track all 100 frames at the mesh nodes, and the endpoint error in voxels
(RMS and 95th percentile) at nodes whose confidence exceeds each threshold, against the
truth nodal motion; and scikit-image's optical_flow_ilk on the same data (on a subset of
frame pairs, it takes ~15 s per pair), sampled at the same nodes, as the reference.

    OMP_NUM_THREADS=1 python benchmarks/bench_tracking.py [--frames 100] [--ilk-pairs 10]
        [--cases warp,warp_noise,scatter,scatter_noise] [--workdir /tmp/liverinv_bench]

Prints one table and writes results/bench_tracking.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from liverinv.imaging.analytic import analytic_run, triangle_depth
from liverinv.imaging.bundle import Indenter, open_bundle, write_bundle
from liverinv.imaging.flow import track_bundle
from liverinv.imaging.grid import paper_grid
from liverinv.imaging.sequence import ImagingOptions, SpeckleScene
from liverinv.imaging.tracking import TrackOptions
from liverinv.imaging.weights import VoxelWeights, mesh_arrays

ROOT = Path(__file__).resolve().parents[1]
MESH = ROOT.parent / "shared" / "benchmark" / "cylinder_coarse.msh"
CASES = {
    "warp": dict(mode="warp"),
    "warp_noise": dict(mode="warp", bmode_noise=0.02),
    "scatter": dict(mode="scatter"),
    "scatter_noise": dict(mode="scatter", noise_db=-25.0, decorrelation=0.01),
}
THRESHOLDS = (0.02, 0.05, 0.1)


def truth_run(args, P, C, grid):
    if args.truth:
        import xarray as xr
        ds = xr.load_dataset(args.truth)
        times = np.linspace(ds.time.values[0], ds.time.values[-1], args.frames)
        return ds, times
    # 100 frames over load/unload; top-centre motion per frame = 0.3 voxel axially
    n_half = (args.frames - 1) / 2
    depth = args.max_motion_vox * grid.spacing_m[2] * n_half
    rate = 2e-3
    times = np.linspace(0, 2 * depth / rate, args.frames)
    return analytic_run(P, C, times, triangle_depth(times, depth, rate)), times


def make_bundle(path, case, ds, times, vw, grid, seed):
    opts = ImagingOptions(seed=seed, **CASES[case])
    scene = SpeckleScene(vw, opts)
    u = ds["u"].interp(time=times).values
    ind = Indenter(times, ds["indenter_depth"].interp(time=times).values,
                   ds["indenter_force"].interp(time=times).values)
    t0 = time.perf_counter()
    write_bundle(path, (scene.frame(u[k]) for k in range(len(times))), grid, times, ind,
                 {"mesh": str(MESH)}, case=case)
    return time.perf_counter() - t0


def errors(est_vox, true_vox):
    return np.linalg.norm(est_vox - true_vox, axis=-1)


def stats(e):
    return {"rms": float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan"),
            "p95": float(np.percentile(e, 95)) if e.size else float("nan"), "n": int(e.size)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--max-motion-vox", type=float, default=0.3)
    ap.add_argument("--ilk-pairs", type=int, default=10)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/liverinv_bench"))
    ap.add_argument("--truth", type=Path, default=None)
    ap.add_argument("--stride", type=int, nargs=3, default=(2, 2, 1))
    ap.add_argument("--iterations", type=int, default=8)
    ap.add_argument("--reuse", action="store_true", help="reuse bundles already in --workdir")
    ap.add_argument("--render-only", action="store_true", help="only write the bundles")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "bench_tracking.json")
    ap.add_argument("--window", default="subtet", choices=["subtet", "element"])
    ap.add_argument("--interpolated-iterations", type=int, default=0)
    ap.add_argument("--min-support", type=float, default=TrackOptions.min_support_vox,
                    help="minimum window radius in voxels (TrackOptions.min_support_vox; 0 = element windows only)")
    args = ap.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    P, C = mesh_arrays(str(MESH))
    grid = paper_grid()
    ds, times = truth_run(args, P, C, grid)
    if args.truth:
        P, C = ds["X"].values, ds["cells"].values
    u = ds["u"].interp(time=times).values                 # (frame, node, 3) m
    true_vox = grid.vec_to_vox(np.diff(u, axis=0))         # (pair, node, 3)
    print(f"truth: {len(times)} frames, max nodal motion {np.abs(true_vox).max():.3f} voxel/frame")
    vw = VoxelWeights.build(P, C, grid)
    results = {}
    for ci, case in enumerate(args.cases.split(",")):
        path = args.workdir / f"{case}.h5"
        if not (args.reuse and path.is_file()):
            t_make = make_bundle(path, case, ds, times, vw, grid, seed=10 + ci)
            print(f"[{case}] rendered {len(times)} volumes in {t_make:.0f} s", flush=True)
        if args.render_only:
            continue
        opts = TrackOptions(max_iterations=args.iterations,
                            interpolated_iterations=args.interpolated_iterations,
                            min_support_vox=args.min_support)
        with open_bundle(path) as b:
            flow = track_bundle(b, P, C, opts, stride=tuple(args.stride), window=args.window)
            est = grid.vec_to_vox(flow["u_of"].values)
            cmin = flow["c_of"].values.min(-1)
            e = errors(est, true_vox)
            res = {"track_seconds": flow.attrs["tracking_seconds"],
                   "cpu_seconds_incl_weights": flow.attrs["cpu_seconds"],
                   "weights_seconds": flow.attrs["weights_seconds"],
                   "mean_iterations": float(flow["iterations"].mean())}
            for th in THRESHOLDS:
                res[f"lk_c>{th}"] = stats(e[cmin > th])
            # head to head with optical_flow_ilk on a subset of pairs
            from skimage.registration import optical_flow_ilk
            pairs = np.unique(np.linspace(1, len(times) - 2, args.ilk_pairs).astype(int))
            e_ilk = {th: [] for th in THRESHOLDS}
            e_lk = {th: [] for th in THRESHOLDS}
            t_ilk = 0.0
            for k in pairs:
                f0, f1 = b.frame(k), b.frame(k + 1)
                t0 = time.perf_counter()
                fl = optical_flow_ilk(f0, f1)
                t_ilk += time.perf_counter() - t0
                xk = grid.to_vox(P + u[k])                   # true node positions at frame k
                v_ilk = np.stack([ndimage.map_coordinates(fl[a], xk.T, order=1, mode="nearest")
                                  for a in range(3)], 1)
                ek = errors(v_ilk, true_vox[k])
                for th in THRESHOLDS:
                    m = cmin[k] > th
                    e_ilk[th].append(ek[m])
                    e_lk[th].append(e[k][m])
            for th in THRESHOLDS:
                res[f"ilk_c>{th}"] = stats(np.concatenate(e_ilk[th]))
                res[f"lk_same_pairs_c>{th}"] = stats(np.concatenate(e_lk[th]))
            res["ilk_seconds_per_pair"] = t_ilk / len(pairs)
            res["ilk_pairs"] = pairs.tolist()
        results[case] = res
        print(f"[{case}] tracked {len(times) - 1} pairs in {res['track_seconds']:.1f} s wall "
              f"(+{res['weights_seconds']:.1f} s weights; {res['cpu_seconds_incl_weights']:.1f} s CPU "
              f"in all), {res['mean_iterations']:.1f} iterations/pair",
              flush=True)
        for th in THRESHOLDS:
            a, s_, i = res[f"lk_c>{th}"], res[f"lk_same_pairs_c>{th}"], res[f"ilk_c>{th}"]
            print(f"   c>{th:<4}: nodal LK rms {a['rms']:.4f} p95 {a['p95']:.4f} ({a['n'] / (len(times) - 1):.0f} nodes/pair)"
                  f" | same {len(pairs)} pairs: LK rms {s_['rms']:.4f} p95 {s_['p95']:.4f}"
                  f" vs ilk rms {i['rms']:.4f} p95 {i['p95']:.4f}", flush=True)
    out = args.out
    out.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()},
                               "results": results}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
