"""The catalog of candidate effects.

Each effect says its amplitude parameter (the one tested; its null value makes the extended
model exactly the fitted one), the physical sign of the amplitude, the parameters that are
undefined at the null and are scanned over a grid, how a full parameter set is moved along
the amplitude (`variant`), and which law of `liverinv.laws` carries it when it is added.

Available: ``shear_relaxation``, ``bulk_relaxation``, ``nonlinear_bulk``,
``strain_stiffening`` (parameters of the solid law, `liverinv.laws.PARAMS`) and
``punch_friction``, ``bottom_slip`` (boundary terms that compose with any solid law,
`liverinv.laws.TERMS`: the law "SR+punch_friction"). Not built yet: ``poroelastic`` as a
diagnosis of a solid fit and ``inclusion``; every diagnosis says that they were not tested.

Adding an effect: one more `Effect(...)` in `CATALOG` with its amplitude, sign, scan and the
parameters it needs in a law (a new boundary term also needs its entry in `laws.TERMS` and
its force in the model).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..laws import LAWS, PARAMS, TERMS, get_law

__all__ = ["Effect", "CATALOG", "available_effects", "law_with", "TAU_GRID_S"]

TAU_GRID_S = tuple(float(v) for v in np.logspace(-2, 1, 7))     # 0.01 .. 10 s, 2 per decade


@dataclass(frozen=True)
class Effect:
    name: str
    description: str              # plain words, for the report
    amplitude: str                # tested parameter: a PARAMS name, or "1/D2"
    unit: str                     # unit of the amplitude as tested
    scale: float = 1.0            # amplitude = scale * (parameter or 1/parameter) in SI
    sign: float = 1.0             # physical direction of the amplitude
    scanned: dict = field(default_factory=dict)   # parameter -> grid of values (SI)
    needs: tuple = ()             # law parameters the effect adds
    available: bool = True
    why_not: str = ""

    def applies_to(self, law: str, fixed=()) -> bool:
        """The law lacks the effect (its parameters are absent, or held at their null)."""
        return self.available and not set(self.needs) <= (set(get_law(law).free) - set(fixed))

    def scan_points(self) -> list[dict]:
        if not self.scanned:
            return [{}]
        (name, grid), = self.scanned.items()
        return [{name: float(v)} for v in grid]

    def variant(self, full: dict, eps: float, scan: dict) -> dict:
        """A full parameter set moved by `eps` along the amplitude (in units of `unit`)."""
        p = dict(full)
        p.update(scan)
        if self.amplitude == "1/D2":
            p["D2"] = 1.0 / (eps * self.scale)
        else:
            p[self.amplitude] = eps * self.scale
        return p

    def estimate(self, theta: float, scan: dict) -> dict:
        """The effect's parameters (SI) for an amplitude `theta` (units of `unit`)."""
        out = dict(scan)
        if self.amplitude == "1/D2":
            out["D2"] = float(1.0 / (theta * self.scale)) if theta > 0 else float("inf")
        else:
            out[self.amplitude] = float(theta * self.scale)
        return out


CATALOG = {e.name: e for e in [
    Effect("shear_relaxation", "the shear stiffness relaxes over time (QLV Prony term on the isochoric stress)",
           "g1", "1", needs=("g1", "tau_g1"), scanned={"tau_g1": TAU_GRID_S}),
    Effect("bulk_relaxation", "the bulk stiffness relaxes over time (QLV Prony term on the volumetric stress)",
           "k1", "1", needs=("k1", "tau_k1"), scanned={"tau_k1": TAU_GRID_S}),
    Effect("nonlinear_bulk", "the volume change stiffens at large compression (quartic bulk term, 1/D2)",
           "1/D2", "kPa", scale=1e3, needs=("D2",)),
    Effect("strain_stiffening", "the shear response stiffens with strain (second reduced-polynomial term C2)",
           "C2", "kPa", scale=1e3, needs=("C2",)),
    Effect("punch_friction", "the punch face holds the tissue tangentially (friction: a tangential spring "
           "on the footprint, k_punch)", "k_punch", "kPa/mm", scale=1e6, needs=("k_punch",)),
    Effect("bottom_slip", "the bottom face slides (a tangential compliance of the support, c_bottom)",
           "c_bottom", "mm/kPa", scale=1e-6, needs=("c_bottom",)),
    Effect("poroelastic", "fluid flows through the solid (Darcy, permeability kappa)", "kappa", "m^4/(N s)",
           available=False, why_not="needs the biphasic model as a composable term of a QLV solid law"),
    Effect("inclusion", "a sphere of other stiffness inside the tissue", "contrast", "1",
           available=False, why_not="needs regional parameter fields as a model term"),
]}


def available_effects(law: str, fixed=()) -> list[Effect]:
    return [e for e in CATALOG.values() if e.applies_to(law, fixed)]


def law_with(law: str, effects) -> tuple[str, dict]:
    """The law with the parameters of `law` and of `effects`: the smallest solid law of
    `liverinv.laws.LAWS` with the material parameters, plus the boundary terms (``+term``),
    and the values that hold its other parameters at their null (no quartic bulk term: D2 at
    its upper bound; no relaxation: amplitude 0)."""
    base, *terms = law.split("+")
    terms = list(terms) + [e for e in effects if e in TERMS and e not in terms]
    boundary = {p for t in terms for p in TERMS[t][0]}
    need = (set(get_law(base).free) | {p for e in effects for p in CATALOG[e].needs}) - boundary
    candidates = [lw for lw in LAWS.values() if need <= set(lw.free) and not lw.biphasic and not lw.fixed]
    if not candidates:
        raise ValueError(f"no law has the parameters {sorted(need)}")
    best = min(candidates, key=lambda lw: len(lw.free))
    null = {"D2": PARAMS["D2"].upper, "g1": 0.0, "tau_g1": 1.0, "k1": 0.0, "tau_k1": 1.0}
    fixed = {k: null[k] for k in best.free if k not in need}
    order = [t for t in TERMS if t in terms]
    return "+".join([best.name, *order]), fixed
