"""The catalog of candidate effects.

Each effect says its amplitude parameter (the one tested; its null value makes the extended
model exactly the fitted one), the physical sign of the amplitude, the parameters that are
undefined at the null and are scanned over a grid, how a full parameter set is moved along
the amplitude (`variant`), and which law of `liverinv.laws` carries it when it is added.

Available: ``shear_relaxation``, ``bulk_relaxation``, ``nonlinear_bulk``,
``strain_stiffening`` (parameters of the solid law, `liverinv.laws.PARAMS`) and
``punch_friction``, ``bottom_slip`` (boundary terms that compose with any solid law,
`liverinv.laws.TERMS`: the law "SR+punch_friction"), and ``poroelastic`` (Darcy flow through
an elastic or SR skeleton: the laws PE and PSR, refitted from the drained null kappa =
`KAPPA_DRAINED`; tested with amplitude 1/kappa by its first-order force on the solid model,
`fem.darcy.DrainedDarcy`, with no biphasic solve, and by secants to the biphasic model of the
fitted skeleton at `KAPPA_SECANTS`), and ``inclusion`` (C1 and C2 scaled by
inc_scale in a sphere; the sphere is scanned over `inclusion_grid`, the contrast tested in
both directions; refitted as the law "+inclusion" with the best sphere held in the model).

Adding an effect: one more `Effect(...)` in `CATALOG` with its amplitude, sign, scan and the
parameters it needs in a law (a new boundary term also needs its entry in `laws.TERMS` and
its force in the model).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..laws import LAWS, PARAMS, TERMS, get_law

__all__ = ["Effect", "Linear", "Reciprocal", "CATALOG", "at_bound", "available_effects", "law_with", "TAU_GRID_S", "KAPPA_DRAINED", "KAPPA_SECANTS",
           "sphere_allowed"]

TAU_GRID_S = tuple(float(v) for v in np.logspace(-2, 1, 7))     # 0.01 .. 10 s, 2 per decade
INCLUSION_OFFSETS_M = (-5e-3, 0.0, 5e-3)
INCLUSION_DEPTHS_M = (6e-3, 10e-3, 14e-3)
INCLUSION_RADII_M = (3.5e-3, 6e-3)
MIN_INCLUSION_ELEMENTS = 4
INCLUSION_MIN_COVER_M = 2e-3
KAPPA_DRAINED = 1e-3    # m^4/(N s): the poroelastic null (consolidation time ~1e-4 s on a 1 cm body)


@dataclass(frozen=True)
class Linear:
    """The law's parameter is `scale` times the amplitude (null 0)."""
    param: str
    scale: float = 1.0

    def __call__(self, a: float) -> float:
        return float(a * self.scale)


@dataclass(frozen=True)
class Reciprocal:
    """The law's parameter is 1 / (1/null + scale a): a compliance or a permeability whose
    null (`null`: inf for no quartic bulk term, KAPPA_DRAINED for drained flow) is a finite
    amplitude 0. Amplitudes at or below 0 give the null."""
    param: str
    scale: float = 1.0
    null: float = np.inf

    def __call__(self, a: float) -> float:
        inv = 1.0 / self.null + a * self.scale
        return float(1.0 / inv) if inv > 0 else float(self.null)


@dataclass(frozen=True)
class Effect:
    name: str
    description: str              # plain words, for the report
    amplitude: str                # the tested amplitude, for the report ("1/D2", "inc_scale - 1")
    unit: str                     # unit of the amplitude as tested
    to_param: Linear | Reciprocal | None = None   # amplitude -> the law's parameter (SI)
    sign: float = 1.0             # physical direction of the amplitude (0: both)
    scanned: dict = field(default_factory=dict)   # parameter -> grid of values (SI)
    needs: tuple = ()             # law parameters the effect adds
    available: bool = True
    why_not: str = ""
    force: Callable | None = None  # fm -> the added term's force direction (`fem.sensitivity`), for an
                                   # effect that no parameter variant of the solid model carries
    rivals: tuple = ()            # effects that explain the same signature another way: when this one
                                  # is refitted as a trial, they are too (`discover.trial_rows`)
    geometric: bool = False       # scanned over spheres of the mesh (an inclusion)
    far: float | None = None      # the amplitude (in `unit`) of the effect in full (a bonded punch, a
                                  # sliding bottom): also tested by the secant to it (`score.diagnose`)
    far_fallback: tuple = ()      # nearly full amplitudes, tried in turn when the solve at `far` fails
    secant_scan: tuple = ()       # amplitudes (in `unit`) at which an effect far from linear in its
                                  # amplitude is also tested by the secant from its null (Darcy flow)
    model_at: Callable | None = None   # (fm, model, params) -> the fitted law's model with the effect's
                                       # parameters `params`, where no parameter variant of the solid
                                       # model carries it (Darcy flow: the biphasic model)

    def saturating_amplitude(self, fraction: float, half: float, full: float | None = None) -> float:
        """The amplitude that gives `fraction` of the full effect (the secant's amplitude `full`,
        default `far`) when the effect saturates like a spring in series with the tissue,
        fraction = a / (a + half) (`half`: the amplitude of half the effect); the full amplitude
        from 0.99 on, or when `half` is unknown."""
        full = self.far if full is None else full
        if fraction >= 0.99 or not half > 0:
            return float(full)
        return float(min(full, half * fraction / (1.0 - fraction)))

    def applies_to(self, law: str, fixed=()) -> bool:
        """The law lacks the effect (its parameters are absent, or held at their null)."""
        return self.available and not set(self.needs) <= (set(get_law(law).free) - set(fixed))

    def scan_points(self, fm=None) -> list[dict]:
        if self.geometric:
            return inclusion_grid(fm.mesh)
        if not self.scanned:
            return [{}]
        (name, grid), = self.scanned.items()
        return [{name: float(v)} for v in grid]

    def direction(self, model, full: dict, eps: float, scan: dict, fm):
        """The sensitivity direction of the amplitude (units of `unit`) on the solid `model`:
        its force direction, or the model with the parameters moved by `eps`."""
        if self.force is not None:
            return self.force(fm)
        return model.with_params(self.variant(full, eps, scan, fm))

    def variant(self, full: dict, eps: float, scan: dict, fm=None) -> dict:
        """A full parameter set moved by `eps` along the amplitude (in units of `unit`)."""
        p = dict(full)
        if self.geometric:
            from ..forward import Inclusion
            inside = Inclusion(tuple(scan["center_m"]), scan["radius_m"], {}).elements(fm.mesh)
            for k in ("C1", "C2"):
                p[k] = np.broadcast_to(np.asarray(full[k], float), inside.shape) * np.where(inside, 1.0 + eps, 1.0)
            return p
        p.update(scan)
        p[self.to_param.param] = self.to_param(eps)
        return p

    def secant_points(self) -> list[float]:
        """The amplitudes (in `unit`) tested by a secant from the null: the full size of an
        effect that saturates, the scan of one far from linear."""
        return ([self.far] if self.far is not None else []) + list(self.secant_scan)

    def secant_model(self, model, full: dict, a: float, fm):
        """The fitted `model` (full parameter set `full`) with the effect at amplitude `a`."""
        p = self.variant(full, a, {}, fm)
        return self.model_at(fm, model, p) if self.model_at is not None else model.with_params(p)

    def physical(self, theta: float) -> bool:
        """Is the one-step amplitude `theta` physical (two-sided effects: a positive stiffness)?"""
        return theta > -0.95 if self.sign == 0 else theta * self.sign > 0

    @property
    def amplitude_param(self) -> str | None:
        """The law's parameter that carries the amplitude (inc_scale for an inclusion)."""
        return "inc_scale" if self.geometric else self.to_param.param if self.to_param else None

    def amplitude_of(self, params: dict, sd: dict | None = None):
        """The amplitude (units of the law's parameter) of fitted `params` and, with their SDs
        `sd` (SI), its SD by the delta method: (amplitude, SD or None: none given, or the
        parameter at a bound of its range, where the SD says nothing: a 10x sphere of warped
        data ends at contrast 50); None for an effect that saturates (`far`: a bonded punch
        ends at its bound) or whose parameter is not in `params`. A sphere's contrast is taken
        on the log scale it is fitted on (ln inc_scale, SD sd/inc_scale), where its Gauss-Newton
        SD means what it says: a stiff sphere's contrast is far from linear in the data (the
        held-out 5x stiffer 5 mm sphere of seed 42, warped, refitted at 38.8 with SD 14, was
        2.7 SDs from 1 in inc_scale and 10 on the log scale)."""
        name = self.amplitude_param
        if self.far is not None or name not in params:
            return None
        p = float(params[name])
        s = float(sd[name]) if sd and sd.get(name, 0) > 0 and not at_bound(name, p) else None
        if self.geometric:      # the contrast on the log scale it is fitted on: ln of inc_scale
            return float(np.log(p)), (s / p if s else None)
        if isinstance(self.to_param, Reciprocal):       # amplitude 1/p - 1/null, its SD s / p^2
            return 1.0 / p - 1.0 / self.to_param.null, (s / (p * p) if s else None)
        return p, s

    def amplitude_z(self, params: dict, sd: dict) -> float | None:
        """How far a fit's amplitude lies from its null, in its SDs (the Wald statistic); None
        where `amplitude_of` gives no amplitude or no SD."""
        a = self.amplitude_of(params, sd)
        return abs(a[0]) / a[1] if a and a[1] else None

    def estimate(self, theta: float, scan: dict) -> dict:
        """The effect's parameters (SI) for an amplitude `theta` (units of `unit`)."""
        if self.geometric:
            return {"inc_scale": float(1.0 + theta), "inclusion_center_m": [float(v) for v in scan["center_m"]],
                    "inclusion_radius_m": float(scan["radius_m"])}
        return {**scan, self.to_param.param: self.to_param(theta)}


def at_bound(name: str, value: float, tol: float = 1e-3) -> bool:
    """Is `value` within `tol` of a bound of the parameter's range (`laws.PARAMS`; in log10
    for a log-scaled parameter, as `Fit.at_bound`)?"""
    par = PARAMS.get(name)
    if par is None:
        return False
    if par.scale == "log":
        return any(b > 0 and value > 0 and abs(np.log10(value / b)) < tol for b in (par.lower, par.upper))
    return min(abs(value - par.lower), abs(value - par.upper)) < tol * (par.upper - par.lower)


def inclusion_grid(mesh) -> list[dict]:
    """Spheres scanned for an inclusion: centres on the punch axis and 5 mm beside it in x and
    y, 6, 10 and 14 mm below the top face; radii 3.5 and 6 mm (54 spheres). Left out: spheres
    that reach within `INCLUSION_MIN_COVER_M` of the top face, where the tracker's own error
    under the punch looks like a stiff layer (on the quick study's null data, with truth and
    model on the same mesh, a 3.5 mm sphere 4 mm deep was recommended: contrast 3.8, predicted
    drop 5 %, p 6e-5), and spheres holding fewer than `MIN_INCLUSION_ELEMENTS` element
    centroids of the model mesh (which it does not resolve)."""
    top = float(mesh.points[:, 2].max())
    spheres = [{"center_m": [x, y, top - z], "radius_m": r} for r in INCLUSION_RADII_M for z in INCLUSION_DEPTHS_M
               for x in INCLUSION_OFFSETS_M for y in INCLUSION_OFFSETS_M]
    return [s for s in spheres if sphere_allowed(mesh, s)]


def sphere_allowed(mesh, sphere: dict) -> bool:
    """A sphere the inclusion may be tested as (`inclusion_grid`'s rules, also for a finer grid
    around its best, `score.refine_inclusion`): at least `INCLUSION_MIN_COVER_M` below the top
    face and holding at least `MIN_INCLUSION_ELEMENTS` element centroids of the model mesh."""
    from ..forward import Inclusion
    depth = float(mesh.points[:, 2].max()) - float(sphere["center_m"][2])
    if depth - sphere["radius_m"] < INCLUSION_MIN_COVER_M - 1e-12:
        return False
    return int(Inclusion(tuple(sphere["center_m"]), sphere["radius_m"], {}).elements(mesh).sum()) >= MIN_INCLUSION_ELEMENTS


def _drained_darcy(fm):
    """The first-order force of Darcy flow at the drained limit, for 1/kappa in 1e7 N s/m^4."""
    from ..fem.darcy import DrainedDarcy
    return DrainedDarcy(fm.space, fm.drained, scale=1e7)


def _biphasic_like(fm, model, params):
    """The biphasic model of the solid `model`'s skeleton (same space, contact and support)
    with the permeability of `params`: on the solid model's own quadrature, so that its
    residual differs from the fitted one by Darcy flow alone (1.4e-3 of the largest at
    the drained null, tests/test_diagnose.py)."""
    from ..fem.biphasic import Biphasic
    return Biphasic(model.space, params, punch=model.punch, support=model.support, drained=fm.drained)


#: Darcy flow's secant scan: kappa 3e-9 and 3e-8 m^4/(N s), a consolidation time of a 6 mm
#: footprint of about 6 s and 0.6 s on liver-like moduli (from 1e-6 on, the first-order score at
#: the drained null sees it). As amplitudes 1/kappa in 1e7 N s/m^4.
KAPPA_SECANTS = (3e-9, 3e-8)

CATALOG = {e.name: e for e in [
    Effect("shear_relaxation", "the shear stiffness relaxes over time (QLV Prony term on the isochoric stress)",
           "g1", "1", Linear("g1"), needs=("g1", "tau_g1"), scanned={"tau_g1": TAU_GRID_S}),
    Effect("bulk_relaxation", "the bulk stiffness relaxes over time (QLV Prony term on the volumetric stress)",
           "k1", "1", Linear("k1"), needs=("k1", "tau_k1"), scanned={"tau_k1": TAU_GRID_S},
           rivals=("poroelastic",)),
    Effect("nonlinear_bulk", "the volume change stiffens at large compression (quartic bulk term, 1/D2)",
           "1/D2", "kPa", Reciprocal("D2", 1e3), needs=("D2",)),
    Effect("strain_stiffening", "the shear response stiffens with strain (second reduced-polynomial term C2)",
           "C2", "kPa", Linear("C2", 1e3), needs=("C2",)),
    Effect("punch_friction", "the punch face holds the tissue tangentially (friction: a tangential spring "
           "on the footprint, k_punch)", "k_punch", "kPa/mm", Linear("k_punch", 1e6), needs=("k_punch",),
           far=1e6,      # 1e12 Pa/m: bonded to 2e-5 in force (tests/test_springs.py)
           # 1e10, then 1e9 Pa/m where the penalty stalls Newton: at the BR fit of warped Darcy flow
           # + bonded punch data, seed 13 (D1 2.5e-5 1/Pa), 1e12 did not solve; 1e10 solved in the
           # diagnosis, not in every setup tried by hand (/tmp/s22/sec.py); 1e9 in every one
           far_fallback=(1e4, 1e3)),
    Effect("bottom_slip", "the bottom face slides (a tangential compliance of the support, c_bottom)",
           "c_bottom", "mm/kPa", Linear("c_bottom", 1e-6), needs=("c_bottom",),
           far=1e4,      # 1e-2 m/Pa: sliding to 1e-3
           far_fallback=(1e3,)),
    Effect("poroelastic", "fluid flows through the solid and carries part of the load (biphasic, Darcy "
           "permeability kappa)", "1/kappa", "1e7 N s/m^4", Reciprocal("kappa", 1e7, KAPPA_DRAINED),
           needs=("kappa",), force=_drained_darcy, rivals=("bulk_relaxation",), secant_scan=tuple(1e-7 / k for k in KAPPA_SECANTS),
           model_at=_biphasic_like),
    Effect("inclusion", "a sphere of other stiffness inside the tissue (C1 and C2 scaled by inc_scale inside)",
           "inc_scale - 1", "1", sign=0.0, needs=("inc_scale",), geometric=True),
]}


def available_effects(law: str, fixed=()) -> list[Effect]:
    """The effects `law` lacks and that some law can add to it."""
    out = []
    for e in CATALOG.values():
        if e.applies_to(law, fixed):
            try:
                get_law(law_with(law, [e.name])[0])
            except ValueError:
                continue
            out.append(e)
    return out


def law_with(law: str, effects) -> tuple[str, dict]:
    """The law with the parameters of `law` and of `effects`: the smallest solid law of
    `liverinv.laws.LAWS` with the material parameters, plus the boundary terms (``+term``),
    and the values that hold its other parameters at their null (no quartic bulk term: D2 at
    its upper bound; no relaxation: amplitude 0)."""
    base, *terms = law.split("+")
    terms = list(terms) + [e for e in effects if e in TERMS and e not in terms]
    boundary = {p for t in terms for p in TERMS[t][0]}
    need = (set(get_law(base).free) | {p for e in effects for p in CATALOG[e].needs}) - boundary
    candidates = [lw for lw in LAWS.values() if need <= set(lw.free) and lw.biphasic == ("kappa" in need)
                  and not lw.fixed]
    if not candidates:
        raise ValueError(f"no law has the parameters {sorted(need)}")
    best = min(candidates, key=lambda lw: len(lw.free))
    null = {"C2": 0.0, "D2": PARAMS["D2"].upper, "g1": 0.0, "tau_g1": 1.0, "k1": 0.0, "tau_k1": 1.0, "kappa": KAPPA_DRAINED}
    fixed = {k: null[k] for k in best.free if k not in need}
    order = [t for t in TERMS if t in terms]
    return "+".join([best.name, *order]), fixed
