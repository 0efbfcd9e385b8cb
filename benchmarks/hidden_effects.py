"""Validation of `liverinv discover` on data with a hidden effect: for each case, a truth
study (config/truths/hidden_bulk.yaml with another law and parameters) is synthesized with
moved-scatterer ultrasound (noise, decorrelation, paper indenter noise), tracked, and
discovered from the elastic law; prints the table of cases.

    python benchmarks/hidden_effects.py --out results/hidden [--cases null shear bulk]
        [--seeds 4] [--mesh tiny|coarse|FILE] [--truth-mesh tiny|fine|FILE] [--frames 100]

--frames N spreads N volumes over the same load/unload cycle (the frame rate follows); the
files of a case then carry `_fN` in their names.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
E = dict(C1=200.0, C2=5000.0, D1=1.5e-3)
SR = dict(E, g1=0.4, tau_g1=0.5)
INCOMPRESSIBLE = dict(C1=300.0, C2=2000.0, D1=3e-4)
#: a creep test: the force ramped to 0.25 N in 2 s (about 5.8 mm on E), held 3 s, unloaded in 2 s;
#: force control from a CSV the benchmark writes beside the study (`creep_force_csv`)
CREEP = {"control": "force", "force_history": "creep_force.csv"}
CREEP_FORCE = ((0.0, 2.0, 5.0, 7.0), (0.0, 0.25, 0.25, 0.0))     # s, N
SHALLOW = {"control": "displacement", "depth": 3.5e-3, "rate": 3.5e-3 / 3, "frames": 31, "unload": True}


def inclusion(contrast, radius_m=0.005, center_m=(0.002, 0.0, 0.0223)):
    """A stiffer sphere (by default 2 mm off the axis, its centre 7.7 mm below the top face)."""
    return {"inclusions": [{"center_m": list(center_m), "radius_m": radius_m,
                            "scale": {"C1": contrast, "C2": contrast}}]}


# case -> (truth law, truth parameters, other keys of the truth study, base law of discover)
CASES = {"null": ("elastic", E, {}, "elastic"), "shear": ("SR", SR, {}, "elastic"),
         "bulk": ("BR", dict(E, D2=1000.0, k1=0.5, tau_k1=0.3), {}, "elastic"),
         # quartic bulk term: +20 % force at 6 mm on the coarse mesh
         "nlbulk": ("elastic_D2", dict(E, D2=3e-4), {}, "elastic"),
         "friction": ("elastic", E, {"contact": {"punch": "bonded"}}, "elastic"),
         "slip": ("elastic", E, {"contact": {"support": "sliding"}}, "elastic"),
         "poro": ("PE", dict(E, kappa=1e-8), {}, "elastic"),
         "inclusion": ("elastic", E, inclusion(3.0), "elastic"),
         # strain stiffening behind a neo-Hookean base (the reduced polynomial's C2 term), and its
         # null; 3.5 mm over the same 6 s cycle: NH folds the coarse mesh's punch rim at 4.75 mm
         "stiffening": ("elastic", E, {"loading": SHALLOW}, "NH"),
         "nh_null": ("NH", dict(C1=600.0, D1=5e-4), {"loading": SHALLOW}, "NH"),
         "sr_null": ("SR", SR, {}, "SR"),
         "sr_poro": ("PSR", dict(SR, kappa=1e-8), {}, "SR"),
         "sr_bulk": ("SBR", dict(SR, D2=1000.0, k1=0.5, tau_k1=0.3), {}, "SR"),
         "sr_bulk_tau3": ("SBR", dict(SR, D2=1000.0, k1=0.5, tau_k1=3.0), {}, "SR"),
         "sr_friction": ("SR", SR, {"contact": {"punch": "bonded"}}, "SR"),
         # detection limits: weaker Darcy flow (larger kappa), stronger inclusions
         "poro_k3e-8": ("PE", dict(E, kappa=3e-8), {}, "elastic"),
         "poro_k1e-7": ("PE", dict(E, kappa=1e-7), {}, "elastic"),
         "poro_k1e-6": ("PE", dict(E, kappa=1e-6), {}, "elastic"),
         # Darcy flow between the diagnosis's secant points (kappa 3e-9 and 3e-8), behind SR
         "sr_poro_k5e-9": ("PSR", dict(SR, kappa=5e-9), {}, "SR"),
         "inclusion_x5": ("elastic", E, inclusion(5.0), "elastic"),
         "inclusion_x10": ("elastic", E, inclusion(10.0), "elastic"),
         # sizes between the null and the limit: partial friction and slip, a softer sphere
         "friction_partial": ("elastic+punch_friction", dict(E, k_punch=1e6), {}, "elastic"),
         "friction_k1e7": ("elastic+punch_friction", dict(E, k_punch=1e7), {}, "elastic"),
         "slip_partial": ("elastic+bottom_slip", dict(E, c_bottom=2e-5), {}, "elastic"),
         "inclusion_soft": ("elastic", E, inclusion(0.2), "elastic"),
         # two effects at once
         "shear_friction": ("SR", SR, {"contact": {"punch": "bonded"}}, "elastic"),
         "poro_slip": ("PE", dict(E, kappa=1e-8), {"contact": {"support": "sliding"}}, "elastic"),
         "poro_friction": ("PE", dict(E, kappa=1e-8), {"contact": {"punch": "bonded"}}, "elastic"),
         "shear_bulk": ("SBR", dict(SR, D2=1000.0, k1=0.5, tau_k1=0.3), {}, "elastic"),
         "shear_poro": ("PSR", dict(SR, kappa=1e-8), {}, "elastic"),
         "sr_slip": ("SR", SR, {"contact": {"support": "sliding"}}, "SR"),
         # session 19, held out: shear relaxation with the quartic bulk term (SBR with k1 0) or
         # with a 10x stiffer sphere, behind elastic; an 8x stiffer 4 mm sphere off the scan's
         # grid (3 mm off axis in x and y, 11.3 mm deep)
         "shear_nlbulk": ("SBR", dict(SR, D2=3e-4, k1=0.0, tau_k1=1.0), {}, "elastic"),
         "shear_inclusion": ("SR", SR, inclusion(10.0), "elastic"),
         "inclusion_x8_off": ("elastic", E, inclusion(8.0, 0.004, (-0.003, 0.003, 0.019)), "elastic"),
         # session 25, held out: the quartic bulk term behind SR; bulk relaxation with a sliding
         # bottom; strain stiffening with shear relaxation behind a neo-Hookean base
         "sr_nlbulk": ("SBR", dict(SR, D2=3e-4, k1=0.0, tau_k1=1.0), {}, "SR"),
         "bulk_slip": ("BR", dict(E, D2=1000.0, k1=0.5, tau_k1=0.3), {"contact": {"support": "sliding"}}, "elastic"),
         "stiffening_shear": ("SR", SR, {"loading": SHALLOW}, "NH"),
         # session 26, held out: an 8x stiffer 4.5 mm sphere on the axis 9 mm deep behind SR; slow
         # shear relaxation (g1 0.3, tau_g1 1.5 s); bulk relaxation with partial punch friction;
         # the quartic bulk term with a sliding bottom; slow Darcy flow (kappa 2e-9, off the
         # secant grid)
         "sr_inclusion": ("SR", SR, inclusion(8.0, 0.0045, (0.0, 0.0, 0.021)), "SR"),
         "slow_shear": ("SR", dict(E, g1=0.3, tau_g1=1.5), {}, "elastic"),
         "bulk_friction": ("BR+punch_friction", dict(E, D2=1000.0, k1=0.5, tau_k1=0.3, k_punch=1e7), {}, "elastic"),
         "nlbulk_slip": ("elastic_D2", dict(E, D2=3e-4), {"contact": {"support": "sliding"}}, "elastic"),
         "poro_k2e-9": ("PE", dict(E, kappa=2e-9), {}, "elastic"),
         # session 27, held out: fast shear relaxation (tau_g1 0.1 s); weak, slow bulk relaxation;
         # a 3x softer 5 mm sphere 6.3 mm off the axis (outside the scan's grid) 9 mm deep; partial
         # punch friction behind SR; shear relaxation with a sliding bottom behind elastic
         "fast_shear": ("SR", dict(E, g1=0.3, tau_g1=0.1), {}, "elastic"),
         "weak_bulk": ("BR", dict(E, D2=1000.0, k1=0.3, tau_k1=1.0), {}, "elastic"),
         "soft_inclusion_off": ("elastic", E, inclusion(1 / 3, 0.005, (0.006, -0.002, 0.021)), "elastic"),
         "sr_friction_k3e6": ("SR+punch_friction", dict(SR, k_punch=3e6), {}, "SR"),
         "shear_slip": ("SR", SR, {"contact": {"support": "sliding"}}, "elastic"),
         # session 32, held out: the quartic bulk term with a bonded punch (two at once; the
         # quartic term was added in place of partial friction in session 31); partial bottom slip
         # behind SR; fast bulk relaxation behind elastic
         "nlbulk_friction": ("elastic_D2", dict(E, D2=3e-4), {"contact": {"punch": "bonded"}}, "elastic"),
         "sr_slip_partial": ("SR+bottom_slip", dict(SR, c_bottom=2e-5), {}, "SR"),
         "fast_bulk": ("BR", dict(E, D2=1000.0, k1=0.4, tau_k1=0.1), {}, "elastic"),
         # and a null behind a biphasic base (PE truth, PE base)
         "pe_null": ("PE", dict(E, kappa=1e-8), {}, "PE"),
         # two boundary effects at once: a bonded punch on a sliding bottom
         "slip_friction": ("elastic", E, {"contact": {"punch": "bonded", "support": "sliding"}}, "elastic"),
         # session 33, held out: other tissues than E. Nulls of a stiffer, nearly incompressible
         # tissue (nu about 0.45, where the coarse mesh locks more) and of a soft, compressible one
         # that stiffens strongly; a null of slow shear relaxation behind SR; shear relaxation hidden
         # in the nearly incompressible tissue
         "null_incompressible": ("elastic", INCOMPRESSIBLE, {}, "elastic"),
         "null_soft": ("elastic", dict(C1=100.0, C2=8000.0, D1=4e-3), {}, "elastic"),
         "sr_null_slow": ("SR", dict(C1=150.0, C2=4000.0, D1=1e-3, g1=0.25, tau_g1=2.0), {}, "SR"),
         "shear_incompressible": ("SR", dict(INCOMPRESSIBLE, g1=0.4, tau_g1=0.5), {}, "elastic"),
         # force-controlled creep tests (the depth creeps while the force is held): shear
         # relaxation behind elastic, and the elastic null
         "creep_shear": ("SR", SR, {"loading": CREEP}, "elastic"),
         "creep_null": ("elastic", E, {"loading": CREEP}, "elastic"),
         # session 37, held out: a sphere with a second effect (two at once): a 3x stiffer 5 mm
         # sphere under a bonded punch; a 4x stiffer 4.5 mm sphere off the scan's grid on a
         # sliding bottom; a 3x softer 5 mm sphere in tissue with Darcy flow
         "inclusion_friction": ("elastic", E, {**inclusion(3.0), "contact": {"punch": "bonded"}}, "elastic"),
         "inclusion_slip": ("elastic", E, {**inclusion(4.0, 0.0045, (-0.004, 0.002, 0.020)),
                                           "contact": {"support": "sliding"}}, "elastic"),
         "poro_inclusion": ("PE", dict(E, kappa=1e-8), inclusion(1 / 3, 0.005, (0.0, -0.003, 0.021)), "elastic"),
         # session 39, held out (two at once, chosen before the first run): bulk relaxation with
         # the quartic bulk term (two volumetric effects); shear relaxation with partial punch
         # friction behind elastic
         "bulk_nlbulk": ("BR", dict(E, D2=3e-4, k1=0.5, tau_k1=0.3), {}, "elastic"),
         "shear_friction_k1e7": ("SR+punch_friction", dict(SR, k_punch=1e7), {}, "elastic")}


def creep_force_csv(path):
    """The force history of `CREEP` (time_s, force_N at 10 Hz) written to `path`; returns its duration (s)."""
    import numpy as np
    t = np.linspace(0.0, CREEP_FORCE[0][-1], int(round(CREEP_FORCE[0][-1] * 10)) + 1)
    np.savetxt(path, np.c_[t, np.interp(t, *CREEP_FORCE)], delimiter=",", header="time_s,force_N", comments="")
    return float(t[-1])


def mesh_file(name, out):
    from liverinv.meshgen import PRESETS, generate_indentation_mesh
    if Path(name).exists():
        return Path(name)
    if name == "fine":
        return ROOT.parent / "shared" / "benchmark" / "cylinder_fine.msh"
    path = out / f"{name}.msh"
    if not path.exists():
        generate_indentation_mesh(path, **PRESETS[name])
    return path


def _fmt(v):
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]" if isinstance(v, list) else f"{v:.4g}"


def sh(*args):
    t = time.perf_counter()
    subprocess.run([str(a) for a in args], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t


def truth_phi_vol(ds, bundle, flow, mesh, law, params, extra):
    """Phi_vol of the truth itself (its law, contact and inclusions) on the model mesh, with
    the noise levels discover used: the floor that tracking error and discretization leave,
    which no added effect can go below."""
    from liverinv.diagnose.files import discovery_objective
    contact = extra.get("contact", {})
    obj = discovery_objective(ds, law, bundle, flow, mesh, punch=contact.get("punch", "frictionless"),
                              support=contact.get("support", "fixed"), inclusions=extra.get("inclusions", ()))
    return float(obj(params).phi_vol)


def main(argv=None):
    import xarray as xr
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "hidden")
    ap.add_argument("--cases", nargs="+", default=list(CASES))
    ap.add_argument("--seeds", type=int, nargs="+", default=[4])
    ap.add_argument("--mesh", default="tiny")
    ap.add_argument("--truth-mesh", default="tiny")
    ap.add_argument("--frames", type=int, help="volumes over the cycle (default: the study's 31)")
    ap.add_argument("--hold", type=float, default=0.0,
                    help="s held at the peak depth (a ramp-hold-unload cycle); the volumes keep the study's "
                         "5 Hz and span the longer cycle")
    ap.add_argument("--mode", choices=["scatter", "warp"], default="scatter",
                    help="volumes of moved scatterers with receiver noise and decorrelation (the study's), or "
                         "the first volume warped (synthesize's default, the paper's way; no receiver noise)")
    ap.add_argument("--bmode-noise", type=float, default=0.0,
                    help="warp mode: std of additive noise on each B-mode volume (0..1 units; the speckle's own std "
                         "is about 0.35)")
    ap.add_argument("--clean-indenter", action="store_true",
                    help="a noise-free indenter record (synthesize's default; the noise levels are then estimated "
                         "from the record, with their floors)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    mesh, tmesh = mesh_file(args.mesh, args.out), mesh_file(args.truth_mesh, args.out)
    base = yaml.safe_load((ROOT / "config/truths/hidden_bulk.yaml").read_text())
    rows = []
    for case in args.cases:
        law, params, extra, base_law = CASES[case]
        for seed in args.seeds:
            study = dict(base, mesh=str(tmesh), law=law, params=params, **extra)
            study["imaging"] = dict(base["imaging"], seed=seed)
            tag = f"{case}_s{seed}"
            if args.mode == "warp":
                study["imaging"] = {k: v for k, v in study["imaging"].items() if k not in ("noise_db", "decorrelation")}
                study["imaging"]["mode"] = "warp"
                study["imaging"]["bmode_noise"] = args.bmode_noise
                tag = f"{case}_warp{f'n{args.bmode_noise:g}' if args.bmode_noise else ''}_s{seed}"
            if args.clean_indenter:
                study["imaging"]["indenter"] = dict(study["imaging"]["indenter"], noise=False)
                tag = tag.replace(f"_s{seed}", f"_ci_s{seed}")
            if study.get("loading", {}).get("force_history") == CREEP["force_history"]:
                # the volumes at the study's frame rate over the whole force record
                cycle_s = creep_force_csv(args.out / CREEP["force_history"])
                study["imaging"]["frames"] = int(round(cycle_s * study["imaging"]["frame_rate_hz"])) + 1
            if args.hold:
                from liverinv.loading import ramp_history
                lo = dict(study.get("loading", base["loading"]), hold=args.hold)
                cycle_s = ramp_history(lo["depth"], lo["rate"], frames=2, unload=lo.get("unload", True),
                                       hold=args.hold).time[-1]
                lo["frames"] = int(round(cycle_s * study["imaging"]["frame_rate_hz"])) + 1
                study["loading"] = lo
                study["imaging"]["frames"] = lo["frames"]
                tag = tag.replace(case, f"{case}_h{args.hold:g}", 1)
            if args.frames:
                # the case's own loading (a hold, the shallow cycle) with frames spread over it
                study["loading"] = dict(study.get("loading", base["loading"]), frames=args.frames)
                study["imaging"].update(frames=args.frames, frame_rate_hz=None)   # evenly over the cycle
                tag = tag.replace(f"_s{seed}", f"_f{args.frames}_s{seed}")
            (args.out / f"{tag}.yaml").write_text(yaml.safe_dump(study))
            b, f, d = args.out / f"{tag}.h5", args.out / f"{tag}_flow.nc", args.out / f"{tag}_disc.nc"
            if not b.exists():
                sh("liverinv", "synthesize", args.out / f"{tag}.yaml", "--out", b)
            if not f.exists():
                sh("liverinv", "track", b, "--mesh", mesh, "--out", f)
            wall = sh("liverinv", "discover", "--bundle", b, "--flow", f, "--mesh", mesh, "--law", base_law,
                      "--out", d) if not d.exists() else float("nan")
            ds = xr.load_dataset(d, engine="h5netcdf")
            last = json.loads(ds.params.values[-1])
            phi_vol = ds.phi_vol.values
            floor = truth_phi_vol(ds, b, f, mesh, law, params, extra)
            removable = (phi_vol[0] - phi_vol[-1]) / (phi_vol[0] - floor) if phi_vol[0] > floor else float("nan")
            steps = range(1, ds.sizes["step"])
            rows.append(f"| {case} | {seed} | {ds.recommended.values[0]} | "
                        f"{', '.join(str(ds.added.values[s]) for s in steps) or 'none'} | "
                        + "; ".join(f"{ds.predicted_drop.values[s]:.3g} / {ds.actual_drop.values[s]:.3g}" for s in steps)
                        + f" | {phi_vol[0]:.4g} -> {phi_vol[-1]:.4g} (truth {floor:.4g}; {removable:.0%} of the removable) | "
                        + ", ".join(f"{k} {_fmt(v)}" for k, v in last.items()) + f" | {wall:.0f} |")
            print(rows[-1], flush=True)
    print("| case | seed | first recommended | added | predicted / actual drop per step | Phi_vol base -> last "
          "| parameters at the last step | discover s |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
