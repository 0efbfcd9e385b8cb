# Input functions and the study table. Every selected study is validated against
# workflow/schemas/study.schema.yaml (liverinv.pipeline.spec) before any job runs.
import hashlib
import json
import os
from pathlib import Path

from snakemake.utils import validate

from liverinv.pipeline.spec import load_workflow_study
from liverinv.study import StudyError

validate(config, schema="../schemas/config.schema.yaml")

RESULTS = config.get("results", "results")
SELECTED = [s for s in str(config["study"]).split(",") if s]
_unknown = [s for s in SELECTED if s not in config["studies"]]
if _unknown:
    raise ValueError(f"config: study {_unknown} not in studies ({', '.join(config['studies'])})")
try:
    STUDY = {name: load_workflow_study(config["studies"][name], name) for name in SELECTED}
except StudyError as e:
    raise ValueError(str(e)) from None

LAWS = sorted({law for s in STUDY.values() for law in s.laws}, key=len, reverse=True)


wildcard_constraints:
    study="|".join(SELECTED),
    law="|".join(LAWS),
    seed="[A-Za-z0-9-]+",
    method="least-squares|nelder-mead",
    preset="tiny|coarse|medium|fine",


def _mesh_file(study, key):
    """A study's mesh (tracking, truth or model) as a file: its path, or the workflow's
    generated preset; None if the study does not set it."""
    path, preset = study.mesh_source(key)
    if preset is not None:
        return f"{RESULTS}/meshes/{preset}.msh"
    return None if path is None else str(path)


def _dataset(study):
    """Data products are shared by studies with the same source (paper-table1 and -table2)."""
    if study.synthetic:
        key = Path(study.spec["truth"]).stem
        return key if "truth_mesh" not in study.spec else f"{key}-{Path(study.spec['truth_mesh']).stem}"
    return f"bundle-{hashlib.sha256(str(study.bundle()).encode()).hexdigest()[:8]}"


def _tracking(study):
    opts = json.dumps(study.spec.get("track", {}), sort_keys=True)
    return f"{Path(study.spec['mesh']).stem}-{hashlib.sha256(opts.encode()).hexdigest()[:6]}"


DATASETS = {_dataset(s): s for s in STUDY.values()}


def data_bundle(study):
    s = STUDY[study] if isinstance(study, str) else study
    return f"{RESULTS}/data/{_dataset(s)}/bundle.h5" if s.synthetic else str(s.bundle())


def data_flow(study):
    s = STUDY[study] if isinstance(study, str) else study
    return f"{RESULTS}/data/{_dataset(s)}/flow_{_tracking(s)}.nc"


def tracking_mesh(study):
    return _mesh_file(STUDY[study] if isinstance(study, str) else study, "mesh")


def truth_inputs(wildcards):
    s = DATASETS[wildcards.dataset]
    out = {"study": str(s.truth_study())}
    mesh = _mesh_file(s, "truth_mesh")
    if mesh:
        out["mesh"] = mesh
    return out


def truth_mesh_option(wildcards, input):
    return f"--mesh {input.mesh}" if "mesh" in input.keys() else ""


def track_inputs(wildcards):
    s = next(s for s in STUDY.values() if _dataset(s) == wildcards.dataset and _tracking(s) == wildcards.tracking)
    return {"bundle": data_bundle(s), "mesh": tracking_mesh(s)}


def track_options(wildcards):
    s = next(s for s in STUDY.values() if _dataset(s) == wildcards.dataset and _tracking(s) == wildcards.tracking)
    args = []
    for key, value in s.spec.get("track", {}).items():
        args.append(f"--{key.replace('_', '-')}")
        args.extend(str(v) for v in (value if isinstance(value, list) else [value]))
    return " ".join(args)


def fit_inputs(wildcards):
    s = STUDY[wildcards.study]
    out = {"bundle": data_bundle(s), "flow": data_flow(s), "mesh": tracking_mesh(s), "study": str(s.path)}
    model = _mesh_file(s, "model_mesh")
    if model:
        out["model_mesh"] = model
    return out


def fit_job_inputs(wildcards):
    """`fit_inputs`, and the first seed's fit when this one reads its design stage."""
    out = fit_inputs(wildcards)
    first = STUDY[wildcards.study].shared_with(_job(wildcards))
    if first:
        out["shared"] = f"{RESULTS}/{wildcards.study}/fits/{first.tag}.nc"
    return out


def _job(wildcards):
    from liverinv.pipeline.spec import FitJob
    return FitJob(wildcards.law, wildcards.seed, wildcards.method)


# the data come before any fit: every fit of a study waits for them (in the three paper studies
# from nothing, the Table 1 data's tracking waited 18 min behind Table 3's fits)
DATA_PRIORITY = 3


def fit_priority(wildcards):
    return STUDY[wildcards.study].fit_priority(_job(wildcards))


def fit_options(wildcards, input):
    s = STUDY[wildcards.study]
    job = _job(wildcards)
    args = s.fit_arguments(job)
    if "model_mesh" in input.keys():
        args += ["--model-mesh", input.model_mesh]
    first = s.shared_with(job)
    if first:
        args += ["--shared-checkpoint", f"{RESULTS}/{wildcards.study}/checkpoints/{first.tag}"]
    return " ".join(f"'{a}'" for a in args)


def fit_files(wildcards):
    s = STUDY[wildcards.study]
    return [f"{RESULTS}/{wildcards.study}/fits/{job.tag}.nc" for job in s.fit_jobs()]


def figure_files(study):
    s = STUDY[study]
    d = f"{RESULTS}/{study}/figures"
    return [*(f"{d}/convergence_{law}.png" for law in s.laws),
            f"{d}/indenter.png", f"{d}/velocities.png", f"{d}/fields.pvd"]


def study_outputs(study):
    s = STUDY[study]
    out = []
    if s.laws:
        out += [f"{RESULTS}/{study}/fits.nc", f"{RESULTS}/{study}/table.csv", f"{RESULTS}/{study}/table.md",
                f"{RESULTS}/{study}/ranking.csv", *figure_files(study)]
    if s.discover:
        out += [f"{RESULTS}/{study}/discovery.nc", f"{RESULTS}/{study}/figures/discovery.png"]
    return out


def discover_options(wildcards, input):
    s = STUDY[wildcards.study]
    final = s.discover.get("final_mesh", "auto")
    args = ["--law", s.discover["law"], "--max-steps", str(s.discover.get("max_steps", 3)),
            "--final-mesh", final if final in ("auto", "none") else str(s.resolve(final))]
    if "model_mesh" in input.keys():
        args += ["--model-mesh", input.model_mesh]
    return " ".join(args)
