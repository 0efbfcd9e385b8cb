"""Workflow studies: a YAML that says where the data come from, how to track them and which
fits to run (laws x named start sets x methods), validated before any job runs.

    >>> s = load_workflow_study("config/studies/quick.yaml")          # doctest: +SKIP
    >>> [j.tag for j in s.fit_jobs()]                                    # doctest: +SKIP
    ['elastic_s1_least-squares', 'elastic_s2_least-squares', ...]
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import yaml

from ..laws import LAWS, PARAMS, TERMS, LawError, get_law
from ..study import StudyError, load_study, read_yaml

__all__ = ["WorkflowStudy", "FitJob", "load_workflow_study", "SCHEMA"]

SCHEMA = Path(__file__).resolve().parents[1] / "schemas" / "workflow_study.schema.yaml"
MESH_PRESETS = ("tiny", "coarse", "medium", "fine")


@dataclass(frozen=True)
class FitJob:
    law: str
    seed: str
    method: str

    @property
    def tag(self) -> str:
        return f"{self.law}_{self.seed}_{self.method}"


@dataclass
class WorkflowStudy:
    name: str
    path: Path
    spec: dict

    @property
    def base(self) -> Path:
        return self.path.parent

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.path.read_bytes()).hexdigest()

    def resolve(self, p) -> Path:
        p = Path(p)
        return p if p.is_absolute() else (self.base / p)

    # --- data -------------------------------------------------------------------------------
    @property
    def synthetic(self) -> bool:
        return "truth" in self.spec

    def truth_study(self) -> Path:
        return self.resolve(self.spec["truth"])

    def bundle(self) -> Path:
        return self.resolve(self.spec["bundle"])

    def mesh_source(self, key="mesh"):
        """(path, None) for a mesh file, (None, preset) for a meshgen preset; key 'mesh' (the
        tracking mesh), 'truth_mesh' (the truth simulation's instead of its study's) or
        'model_mesh' (the forward model's); (None, None) if not set."""
        value = {"mesh": self.spec["mesh"], "truth_mesh": self.spec.get("truth_mesh"),
                 "model_mesh": self.spec.get("fit", {}).get("model_mesh")}[key]
        if value is None:
            return None, None
        if value in MESH_PRESETS:
            return None, value
        return self.resolve(value), None

    def truth_params(self) -> dict:
        if "truth_params" in self.spec:
            return dict(self.spec["truth_params"])
        if self.synthetic:
            truth, _ = load_study(self.truth_study())
            return {k: float(v) for k, v in truth.get("params", {}).items()}
        return {}

    # --- fits -------------------------------------------------------------------------------
    @property
    def laws(self) -> list:
        return list(self.spec.get("fit", {}).get("laws", []))

    @property
    def seeds(self) -> list:
        return list(self.spec.get("fit", {}).get("seeds", {}))

    @property
    def methods(self) -> list:
        return list(self.spec.get("fit", {}).get("methods", ["least-squares"]))

    @property
    def discover(self) -> dict | None:
        return self.spec.get("discover")

    def fit_jobs(self) -> list[FitJob]:
        return [FitJob(law, seed, method) for law in self.laws for seed in self.seeds for method in self.methods]

    def start(self, law: str, seed: str) -> dict:
        """The start parameters of `law` from seed set `seed`: the set's values of the law's
        free parameters (not those held fixed), the law's defaults for the rest."""
        fit = self.spec["fit"]
        lw = get_law(law)
        fixed = fit.get("fixed", {}).get(law, {})
        given = fit["seeds"][seed]
        return {k: float(given.get(k, lw.defaults.get(k))) for k in lw.free if k not in fixed}

    def fixed(self, law: str) -> dict:
        return dict(self.spec["fit"].get("fixed", {}).get(law, {}))

    def fit_arguments(self, job: FitJob) -> list[str]:
        """The options of `liverinv fit` for one job, apart from the data and output paths."""
        fit = self.spec.get("fit", {})
        args = ["--law", job.law, "--method", job.method]
        args += [f"--start={k}={v!r}" for k, v in self.start(job.law, job.seed).items()]
        args += [f"--fixed={k}={v!r}" for k, v in self.fixed(job.law).items()]
        for key, opt in (("observation", "--observation"), ("objective", "--objective"),
                         ("quadrature_order", "--quadrature-order"), ("jacobian", "--jacobian")):
            if key in fit and not (key == "jacobian" and job.method != "least-squares"):
                args += [opt, str(fit[key])]
        if fit.get("tracker_response"):
            args += ["--tracker-response"]
        if job.method == "least-squares":
            for key, opt in (("design_points", "--design-points"), ("polish", "--polish"),
                             ("probe_evaluations", "--probe-evaluations"), ("max_evaluations", "--max-evaluations")):
                if key in fit:
                    args += [opt, str(fit[key])]
        elif "nelder_mead_evaluations" in fit:
            args += ["--max-evaluations", str(fit["nelder_mead_evaluations"])]
        return args

    def shared_with(self, job: FitJob) -> FitJob | None:
        """The fit whose checkpoint `job` reads solves from: a least-squares fit with a design
        stage screens the same design points from every start and polishes the same best ones,
        so every seed after the first of its law and method reads them back from the first
        seed's checkpoint (its job waits for that fit) instead of solving them again."""
        if not self._has_design_stage(job):
            return None
        first = FitJob(job.law, self.seeds[0], job.method)
        return None if first == job else first

    def fit_priority(self, job: FitJob) -> int:
        """The workflow's order among ready fits, longest chains first: 2 for a fit whose
        checkpoint later seeds wait for, 1 for another fit with a design stage (the longest),
        0 otherwise. (Measured in paper-table1..3 from nothing: Snakemake started Table 2's first
        seed after four of Table 3's fits, and its two other seeds waited for it at the end.)"""
        if any(self.shared_with(j) == job for j in self.fit_jobs()):
            return 2
        return 1 if self._has_design_stage(job) else 0

    def _has_design_stage(self, job: FitJob) -> bool:
        return job.method == "least-squares" and int(self.spec.get("fit", {}).get("design_points", 0)) > 0

    @property
    def agree_tol(self) -> float:
        return float(self.spec.get("fit", {}).get("agree_tol", 0.02))


def _fail(path, key, msg):
    raise StudyError(f"{path}: {key}: {msg}")


def validate_workflow_study(spec, path) -> dict:
    """Schema first, then what a schema cannot say: laws and parameter names exist, every seed
    set is a valid start of every law, the files named exist."""
    import jsonschema

    if not isinstance(spec, dict):
        raise StudyError(f"{path}: a workflow study is a mapping of keys (truth or bundle, mesh, fit)")
    schema = yaml.safe_load(SCHEMA.read_text())
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(spec), key=lambda e: list(e.path))
    if errors:
        e = errors[0]
        where = "/".join(str(p) for p in e.path) or "(top level)"
        msg = e.message
        if e.validator == "oneOf" and not e.path:
            msg = "give exactly one of 'truth' (a truth study to render) or 'bundle' (a measurement bundle)"
        elif e.validator == "additionalProperties":
            allowed = sorted(_subschema(schema, e.path).get("properties", {}))
            msg += f"; allowed keys: {', '.join(allowed)}"
        raise StudyError(f"{path}: {where}: {msg}")
    base = Path(path).parent
    fit = spec.get("fit", {"laws": [], "seeds": {}})
    def known(law):
        try:
            get_law(law)
        except LawError:
            return False
        return "inc_scale" not in get_law(law).free     # (a fitted inclusion needs its sphere: liverinv fit)

    if "discover" in spec and not known(spec["discover"]["law"]):
        _fail(path, "discover/law", f"unknown law {spec['discover']['law']!r}; known: {', '.join(LAWS)} "
                                    f"(optionally + {' or + '.join(t for t in TERMS if t != 'inclusion')})")
    for law in fit["laws"]:
        if not known(law):
            _fail(path, "fit/laws", f"unknown law {law!r}; known: {', '.join(LAWS)} "
                                    f"(optionally + {' or + '.join(t for t in TERMS if t != 'inclusion')})")
    for law, values in fit.get("fixed", {}).items():
        if law not in fit["laws"]:
            _fail(path, f"fit/fixed/{law}", f"not one of the study's laws {fit['laws']}")
        bad = [k for k in values if k not in get_law(law).free]
        if bad:
            _fail(path, f"fit/fixed/{law}", f"{law} has no parameter {bad}; its parameters: {', '.join(get_law(law).free)}")
    for seed, values in fit["seeds"].items():
        unknown = [k for k in values if k not in PARAMS]
        if unknown:
            _fail(path, f"fit/seeds/{seed}", f"unknown parameter(s) {unknown}; known: {', '.join(PARAMS)}")
        used = set()
        for law in fit["laws"]:
            lw = get_law(law)
            fixed = fit.get("fixed", {}).get(law, {})
            start = {k: v for k, v in values.items() if k in lw.free and k not in fixed}
            used |= set(start)
            try:
                lw.resolve({**start, **fixed})
            except LawError as e:
                _fail(path, f"fit/seeds/{seed}", f"not a valid start of {law}: {e}")
        unused = sorted(set(values) - used)
        if unused:
            _fail(path, f"fit/seeds/{seed}", f"parameter(s) {unused} belong to none of the laws {fit['laws']}")
    for key in ("truth", "bundle"):
        if key in spec and not (base / spec[key]).is_file():
            _fail(path, key, f"file {base / spec[key]} not found")
    if "truth" in spec:
        truth, _ = load_study(base / spec["truth"])
        if "imaging" not in truth:
            _fail(path, "truth", f"{spec['truth']} has no imaging section to render")
    for key, value in (("mesh", spec["mesh"]), ("truth_mesh", spec.get("truth_mesh")),
                       ("fit/model_mesh", fit.get("model_mesh"))):
        if value is not None and value not in MESH_PRESETS and not (base / value).is_file():
            _fail(path, key, f"{value}: neither a mesh file (relative to the study) nor a preset "
                             f"({', '.join(MESH_PRESETS)})")
    final = spec.get("discover", {}).get("final_mesh", "auto")
    if final not in ("auto", "none") and not (base / final).is_file():
        _fail(path, "discover/final_mesh", f"{final}: neither auto, none nor a mesh file (relative to the study)")
    return spec


def _subschema(schema, path):
    s = schema
    for p in path:
        props = s.get("properties", {})
        s = props[p] if p in props else s.get("additionalProperties", {})
    return s


def load_workflow_study(path, name: str | None = None) -> WorkflowStudy:
    """Read and validate a workflow study YAML (named after its file unless `name`)."""
    path = Path(path)
    spec = read_yaml(path)
    validate_workflow_study(spec, path)
    return WorkflowStudy(name or path.stem, path.resolve(), spec)
