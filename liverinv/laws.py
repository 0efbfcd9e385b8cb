"""Named constitutive laws: which parameters each one has, their units and bounds.

Add a law by adding one entry to `LAWS`. Every law is a subset of the general form of the
seed paper (Eqs. 9-11, plus the biphasic permeability of Eq. 7): parameters not listed as
free take the value in `fixed`, or the neutral value of `NEUTRAL` (no quartic bulk term, no
relaxation, frictionless punch, bonded bottom).

Boundary terms compose with any law by name (the biphasic ones too): ``"SR+punch_friction"`` is SR with the
tangential stiffness of the punch footprint ``k_punch`` as one more free parameter,
``"elastic+bottom_slip"`` elastic with the tangential compliance of the bottom face
``c_bottom``, ``"elastic+inclusion"`` elastic with the stiffness contrast ``inc_scale`` of a
sphere that the forward model holds (`forward.Inclusion` with scale "fitted") (`TERMS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .fem.boundary import C_SLIDING

__all__ = ["Param", "Law", "PARAMS", "LAWS", "get_law", "LawError", "reading_notes"]


class LawError(ValueError):
    """Unknown law, unknown parameter or a value out of bounds."""


@dataclass(frozen=True)
class Param:
    name: str
    unit: str
    lower: float
    upper: float
    scale: str  # "log": optimized in log space; "linear": bounded fraction
    description: str
    search: tuple  # (low, high): range of the multi-start design (soft tissue, this test)
    undetermined: str = ""   # how to read a fit that leaves it at a bound or undetermined (`reading_notes`)


PARAMS = {p.name: p for p in [
    Param("C1", "Pa", 1e-2, 1e5, "log", "first reduced-polynomial coefficient (mu0 = 2 C1)", (10.0, 1e4)),
    Param("C2", "Pa", 0.0, 1e6, "log", "second reduced-polynomial coefficient (stiffening)", (10.0, 1e5)),
    Param("D1", "1/Pa", 1e-7, 1.0, "log", "linear bulk compliance (K0 = 2 / D1)", (1e-5, 1e-1)),
    Param("D2", "1/Pa", 1e-9, 1e3, "log", "quartic bulk compliance (absent: no quartic term)", (1e-4, 1e2)),
    Param("g1", "1", 0.0, 0.999, "linear", "relative shear relaxation amplitude", (0.05, 0.95)),
    Param("tau_g1", "s", 1e-4, 1e3, "log", "shear relaxation time", (1e-2, 1e1)),
    Param("k1", "1", 0.0, 0.999, "linear", "relative bulk relaxation amplitude", (0.05, 0.95)),
    Param("tau_k1", "s", 1e-4, 1e3, "log", "bulk relaxation time", (1e-2, 1e1)),
    Param("kappa", "m^4/(N s)", 1e-15, 1e-3, "log", "Darcy permeability of the biphasic mixture", (1e-10, 1e-5)),
    Param("k_punch", "Pa/m", 0.0, 1e12, "log", "tangential stiffness of the punch footprint per area "
          "(0: frictionless; 1e12, the bound: bonded, to 0.06 um at 6 mm; 1e8 is 0.27 mm off)", (1e4, 1e9),
          "near either end of its range the data cannot tell it from that end (frictionless near 0, bonded "
          "near 1e12 Pa/m), so its SD says nothing there: read it as a frictionless or a bonded punch"),
    Param("c_bottom", "m/Pa", 0.0, C_SLIDING, "log", "tangential compliance of the bottom face per area "
          "(0: bonded; 1e-2, the bound: sliding, the sliding support's own; 1e-4 is 1.3 % stiffer)", (1e-8, 1e-4),
          "near either end of its range the data cannot tell it from that end (bonded near 0, sliding near "
          f"{C_SLIDING:g} m/Pa), so its SD says nothing there: read it as a bonded or a sliding bottom"),
    Param("inc_scale", "1", 0.02, 50.0, "log", "stiffness contrast of the fitted inclusion (C1 and C2 inside "
          "over outside; its sphere is the forward model's)", (0.2, 5.0),
          # the held-out 3x stiffer 5 mm sphere of seed 34 (warped) was added as a 3.5 mm sphere
          # 6.1x stiffer; refitted with the sphere held at six sizes and places, Phi_vol moved by
          # 2.4 % while the contrast went from 1.8 to 12.7 (docs/diagnosis.md, session 32)
          "the data fix how much the sphere stiffens or softens the tissue where it lies, not its radius "
          "and contrast apart: a smaller, stiffer sphere fits about as well as a larger, less stiff one, "
          "so a contrast at a bound of its range (0.02, 50) or with a large SD says 'a stiffer (softer) region "
          "here', not that value"),
]}


def reading_notes(names) -> list[str]:
    """How to read the parameters `names` that a fit left at a bound or undetermined, for
    those with a note (`Param.undetermined`): one line each, "NAME: note"."""
    return [f"{n}: {PARAMS[n].undetermined}" for n in dict.fromkeys(names) if n in PARAMS and PARAMS[n].undetermined]

# boundary terms that compose with any solid law ("LAW+term"): term -> (its parameters, defaults)
TERMS = {
    "punch_friction": (("k_punch",), {"k_punch": 1e6}),
    "bottom_slip": (("c_bottom",), {"c_bottom": 1e-6}),
    "inclusion": (("inc_scale",), {"inc_scale": 1.0}),
}

# value a parameter takes when a law does not have it
NEUTRAL = {"D2": math.inf, "g1": 0.0, "tau_g1": 1.0, "k1": 0.0, "tau_k1": 1.0, "kappa": math.nan,
           "k_punch": 0.0, "c_bottom": 0.0, "inc_scale": 1.0}


@dataclass(frozen=True)
class Law:
    name: str
    description: str
    free: tuple
    fixed: dict = field(default_factory=dict)
    defaults: dict = field(default_factory=dict)
    biphasic: bool = False

    @property
    def units(self) -> dict:
        return {p: PARAMS[p].unit for p in self.free}

    def bounds(self, name) -> tuple:
        return PARAMS[name].lower, PARAMS[name].upper

    def resolve(self, given: dict | None = None) -> dict:
        """Complete parameter set (all of PARAMS) from the values `given` for the free
        parameters, falling back on the law's defaults; checks names and bounds."""
        given = dict(given or {})
        unknown = [k for k in given if k not in self.free]
        if unknown:
            fixed = [k for k in unknown if k in self.fixed]
            if fixed:
                raise LawError(f"law {self.name!r} fixes {fixed} (at {self.fixed}); they cannot be set")
            raise LawError(f"law {self.name!r} has no parameter(s) {unknown}; its parameters are {list(self.free)}")
        out = dict(NEUTRAL)
        out.update(self.fixed)
        for k in self.free:
            if k in given:
                v = given[k]
            elif k in self.defaults:
                v = self.defaults[k]
            else:
                raise LawError(f"law {self.name!r} needs parameter {k!r} ({PARAMS[k].unit})")
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise LawError(f"parameter {k}={v!r} is not a number") from None
            lo, hi = self.bounds(k)
            if not (lo <= v <= hi) or math.isnan(v):
                raise LawError(f"parameter {k}={v:g} {PARAMS[k].unit} is outside its bounds [{lo:g}, {hi:g}]")
            out[k] = v
        return out


_HYPER = dict(C1=200.0, C2=5000.0, D1=1.5e-3)
LAWS = {law.name: law for law in [
    Law("NH", "neo-Hookean: reduced polynomial hyperelasticity with its first term only (C2 = 0)",
        ("C1", "D1"), fixed=dict(C2=0.0), defaults=dict(C1=200.0, D1=1.5e-3)),
    Law("elastic", "reduced polynomial hyperelasticity (Eq. 9 with D2 absent)",
        ("C1", "C2", "D1"), defaults=_HYPER),
    Law("elastic_D2", "reduced polynomial hyperelasticity with quartic bulk term (Eq. 9)",
        ("C1", "C2", "D1", "D2"), defaults=dict(_HYPER, D2=1e-2)),
    Law("SR", "QLV, shear relaxation (Eqs. 9-10, D2 absent, k1 = 0)",
        ("C1", "C2", "D1", "g1", "tau_g1"), defaults=dict(_HYPER, g1=0.4, tau_g1=0.06)),
    Law("SR_low", "SR with low bulk compliance D1 = 1e-4 fixed",
        ("C1", "C2", "g1", "tau_g1"), fixed=dict(D1=1e-4), defaults=dict(C1=200.0, C2=5000.0, g1=0.4, tau_g1=0.06)),
    Law("SR_high", "SR with high bulk compliance D1 = 3e-3 fixed",
        ("C1", "C2", "g1", "tau_g1"), fixed=dict(D1=3e-3), defaults=dict(C1=200.0, C2=5000.0, g1=0.4, tau_g1=0.06)),
    Law("BR", "QLV, bulk relaxation with quartic bulk term, no shear relaxation (Eqs. 9, 11)",
        ("C1", "C2", "D1", "D2", "k1", "tau_k1"),
        defaults=dict(_HYPER, D2=1e-2, k1=0.5, tau_k1=0.1)),
    Law("SBR", "QLV, shear and bulk relaxation (Eqs. 9-11)",
        ("C1", "C2", "D1", "D2", "g1", "tau_g1", "k1", "tau_k1"),
        defaults=dict(_HYPER, D2=1e-2, g1=0.4, tau_g1=0.06, k1=0.5, tau_k1=0.1)),
    Law("PE", "biphasic poroelastic: reduced polynomial skeleton (Eq. 6) saturated by a Darcy "
        "fluid of permeability kappa (Eq. 7)", ("C1", "C2", "D1", "kappa"),
        defaults=dict(_HYPER, kappa=1e-7), biphasic=True),
    Law("PSR", "biphasic poroelastic with a QLV skeleton: PE whose skeleton relaxes in shear as SR",
        ("C1", "C2", "D1", "g1", "tau_g1", "kappa"),
        defaults=dict(_HYPER, g1=0.4, tau_g1=0.06, kappa=1e-7), biphasic=True),
]}


def get_law(name: str) -> Law:
    """The law `name`: one of `LAWS`, or one of them with boundary terms, ``"SR+punch_friction"``."""
    if name in LAWS:
        return LAWS[name]
    base, *terms = str(name).split("+")
    if base not in LAWS:
        raise LawError(f"unknown law {name!r}; known laws: {', '.join(LAWS)} "
                       f"(optionally with + {' or + '.join(TERMS)})")
    bad = [t for t in terms if t not in TERMS]
    if bad or len(set(terms)) < len(terms):
        raise LawError(f"law {name!r}: unknown or repeated term(s) {bad or terms}; boundary terms: {', '.join(TERMS)}")
    law = LAWS[base]
    extra = [p for t in terms for p in TERMS[t][0]]
    defaults = dict(law.defaults)
    for t in terms:
        defaults.update(TERMS[t][1])
    return Law(name, f"{law.description}, with {' and '.join(t.replace('_', ' ') for t in terms)}",
               law.free + tuple(extra), fixed=dict(law.fixed), defaults=defaults, biphasic=law.biphasic)
