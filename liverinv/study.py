"""Study files: YAML validated against `schemas/study.schema.yaml` before any work starts,
and the forward simulation they describe."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import yaml

from .fem.solver import NewtonOptions
from .forward import ForwardModel, force_history_of
from .loading import LoadHistory, ramp_history, read_force_history

__all__ = ["load_study", "validate_study", "validate_imaging", "history_of", "simulate_study", "StudyError"]

SCHEMA = Path(__file__).parent / "schemas" / "study.schema.yaml"


class StudyError(ValueError):
    pass


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads 1e-3 (no dot) as a float, as YAML 1.2 and people do."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                |\.[0-9_]+(?:[eE][-+][0-9]+)?
                |[-+]?\.(?:inf|Inf|INF)
                |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))


_TYPE_NAMES = {"object": "a mapping", "array": "a list", "number": "a number",
               "integer": "an integer", "string": "a string", "boolean": "true or false",
               "null": "null"}


def _schema() -> dict:
    return yaml.safe_load(SCHEMA.read_text())


def _describe(e) -> str:
    """One readable sentence for a jsonschema error: unknown keys with the allowed ones,
    a value outside an enum with the allowed values, a range or type violated."""
    kind, val, inst = e.validator, e.validator_value, e.instance
    if kind == "additionalProperties" and isinstance(inst, dict):
        allowed = list(e.schema.get("properties", {}))
        unknown = [k for k in inst if k not in allowed]
        keys = ", ".join(repr(k) for k in unknown)
        return (f"unknown key{'s' if len(unknown) > 1 else ''} {keys}; "
                f"allowed keys: {', '.join(allowed)}")
    if kind == "enum":
        return f"{inst!r} is not allowed; allowed values: {', '.join(str(v) for v in val)}"
    if kind == "type":
        types = val if isinstance(val, list) else [val]
        return f"{inst!r} is not {' or '.join(_TYPE_NAMES.get(t, t) for t in types)}"
    ops = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=", "exclusiveMaximum": "<"}
    if kind in ops:
        return f"{inst!r} is out of range; it must be {ops[kind]} {val}"
    if kind in ("minItems", "maxItems"):
        lo, hi = e.schema.get("minItems"), e.schema.get("maxItems")
        n = f"exactly {lo}" if lo == hi else (f"at least {lo}" if kind == "minItems" else f"at most {hi}")
        return f"{inst!r} has {len(inst)} item(s); it needs {n}"
    if kind == "required":
        missing = [k for k in val if isinstance(inst, dict) and k not in inst]
        return f"missing key {', '.join(repr(k) for k in missing)}"
    return e.message


def _check(instance, schema, source) -> None:
    import jsonschema

    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(instance),
                    key=lambda e: [str(p) for p in e.path])
    if errors:
        e = errors[0]
        where = "/".join(str(p) for p in e.path) or "(top level)"
        raise StudyError(f"{source}: {where}: {_describe(e)}")


def validate_study(study: dict, source="study") -> dict:
    """`study` checked against `schemas/study.schema.yaml`; StudyError naming `source`, the
    key path (e.g. imaging/volume) and what is allowed there."""
    _check(study, _schema(), source)
    return study


def validate_imaging(imaging, source="study") -> None:
    """The `imaging:` section alone checked against its part of the study schema."""
    sub = _schema()["properties"]["imaging"]
    _check({"imaging": imaging}, {"type": "object", "properties": {"imaging": sub}}, source)


def read_yaml(path):
    """The parsed YAML of a study file (1e-3 read as a number); StudyError naming the file."""
    path = Path(path)
    try:
        return yaml.load(path.read_text(), Loader=_Loader)
    except FileNotFoundError:
        raise StudyError(f"{path}: study file not found") from None
    except yaml.YAMLError as e:
        raise StudyError(f"{path}: not valid YAML ({e})") from None


def load_study(path) -> tuple[dict, Path]:
    """Read and validate a study YAML; returns (study, directory of the file)."""
    path = Path(path)
    study = read_yaml(path)
    if not isinstance(study, dict):
        raise StudyError(f"{path}: a study is a mapping of keys (mesh, law, loading, ...)")
    return validate_study(study, str(path)), path.parent


def _resolve(p, base_dir: Path) -> Path:
    p = Path(p)
    return p if p.is_absolute() else (base_dir / p)


def history_of(loading: dict, base_dir: Path = Path(".")) -> LoadHistory:
    """The displacement history a `loading` section describes (force control: the CSV)."""
    control = loading.get("control", "displacement")
    if control == "force" and loading.get("force_history"):
        return read_force_history(_resolve(loading["force_history"], base_dir))
    missing = [k for k in ("depth", "rate") if k not in loading]
    if missing:
        raise StudyError(f"loading needs {missing} for a displacement ramp")
    return ramp_history(loading["depth"], loading["rate"], steps=loading.get("steps"),
                        frames=loading.get("frames"), unload=loading.get("unload", True),
                        hold=loading.get("hold", 0.0))


def options_of(study: dict) -> NewtonOptions:
    s = study.get("solver", {})
    kw = {}
    if "method" in s:
        kw["method"] = s["method"]
    if "rtol" in s:
        kw["rtol"] = s["rtol"]
    if "linear_solver" in s:
        kw["solver"] = s["linear_solver"]
    return NewtonOptions(**kw)


def with_times(hist: LoadHistory, times) -> LoadHistory:
    """`hist` sampled also at `times` (within its span), the value interpolated linearly
    (exact for the piecewise-linear ramps and force records the engine is driven with)."""
    times = np.asarray(times, dtype=float)
    times = times[(times > hist.time[0]) & (times < hist.time[-1])]
    t = np.unique(np.concatenate([hist.time, times]))
    t = t[np.concatenate([[True], np.diff(t) > 1e-9 * max(hist.time[-1], 1.0)])]
    return LoadHistory(hist.control, t, np.interp(t, hist.time, hist.value))


def simulate_study(study: dict, base_dir: Path = Path("."), extra_times=None):
    """Run the forward simulation of a (validated) study; returns the run Dataset.

    Force control without a CSV (`drive: own`) first runs the displacement-controlled
    history and then drives the model with the force it produced. `extra_times` (s) are
    added to the history's frames (e.g. the imaging frame times, so that every image shows
    an equilibrium state rather than an interpolation between frames)."""
    validate_study(study)
    contact = study.get("contact", {})
    fm = ForwardModel(_resolve(study["mesh"], base_dir), contact.get("punch", "frictionless"),
                      contact.get("support", "fixed"),
                      quadrature_order=study.get("solver", {}).get("quadrature_order", 2),
                      inclusions=study.get("inclusions", ()),
                      **({"drained": study["drainage"]["drained"]} if "drained" in study.get("drainage", {}) else {}))
    loading = study["loading"]
    hist = history_of(loading, base_dir)
    if extra_times is not None:
        hist = with_times(hist, extra_times)
    opts = options_of(study)
    params, regions = study.get("params", {}), study.get("region_params")
    if loading.get("control", "displacement") == "force" and hist.control == "displacement":
        ds_disp = fm.run(study["law"], params, hist, opts, regions)
        hist = force_history_of(ds_disp)
    return fm.run(study["law"], params, hist, opts, regions)
