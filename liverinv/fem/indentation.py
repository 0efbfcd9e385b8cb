"""The indentation boundary-value problem: a tissue body, a rigid flat punch, a support.

Unknowns are the free nodal displacements plus one punch depth d (positive into the tissue).
Footprint nodes follow the punch: u_z = -d (frictionless: u_x, u_y free; bonded: u_x = u_y = 0).
The bottom is fixed (u = 0) or sliding (u_z = 0, its rigid in-plane motion held as `boundary`
says: by pins on the axis, or by a spring of compliance C_SLIDING). The reduced residual's punch
entry is the indenter force (positive compressive) minus the applied force.

Partial friction and slip are tangential springs (`springs.FaceSpring`): the parameter
``k_punch`` (Pa/m) on the footprint of a frictionless punch (0: frictionless), and, with
``support="compliant"`` (u_z = 0 on the bottom, u_x and u_y free), a spring of stiffness
``1 / (c_bottom + C_BONDED)`` on the bottom face (``c_bottom`` in m/Pa; 0: bonded to within
C_BONDED, a compliance 1e-6 of the tissue's over a millimetre).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .assembly import ReducedAssembler
from .boundary import C_SLIDING, constrained_components, displacement_numbering, face_springs
from .material import Kinematics, QLVState, element_stiffness, hyperelastic_terms, qlv_commit, qlv_relaxed_stress
from .space import Space
from .springs import SpringTerms

__all__ = ["Indentation", "Evaluation"]

log = logging.getLogger(__name__)

C_BONDED = 1e-12     # m/Pa: the compliant bottom's own compliance at c_bottom = 0


@dataclass
class Evaluation:
    r: np.ndarray           # reduced internal force (punch entry: indenter force)
    K: object               # reduced tangent (CSR) or None
    S0_iso: np.ndarray
    S0_vol: np.ndarray
    J_min: float


def _scalar(v, name) -> float:
    a = np.unique(np.asarray(v, dtype=float))
    if a.size != 1:
        raise ValueError(f"{name} must be one value for the whole face, not per element")
    return float(a[0])


def spring_stiffnesses(params, punch_spring, support) -> tuple[float, float]:
    """(k_punch, k_bottom) of the footprint's and the bottom's tangential springs from the
    parameters k_punch and c_bottom (k_bottom = 1 / (c_bottom + C_BONDED); a sliding bottom's
    spring 1 / C_SLIDING), checked against the punch contact and the support."""
    k_punch = _scalar(params.get("k_punch", 0.0), "k_punch")
    c_bottom = _scalar(params.get("c_bottom", 0.0), "c_bottom")
    if k_punch < 0 or c_bottom < 0:
        raise ValueError("k_punch and c_bottom must be >= 0")
    if k_punch > 0 and punch_spring is None:
        raise ValueError("k_punch needs a frictionless punch (a bonded punch holds the footprint already)")
    if c_bottom > 0 and support != "compliant":
        raise ValueError("c_bottom needs support='compliant'")
    return k_punch, 1.0 / ((C_SLIDING if support == "sliding" else c_bottom) + C_BONDED)


class Indentation(SpringTerms):
    """Finite-strain indentation model on a tet10 space.

    Parameters
    ----------
    space : Space
    params : dict of parameter name -> scalar or (ne,) array (per element), as resolved by
        `liverinv.laws.Law.resolve` (C1, C2, D1, D2, g1, tau_g1, k1, tau_k1).
    punch : "frictionless" or "bonded"
    support : "fixed", "sliding" or "compliant" (tangential spring, parameter c_bottom)
    """

    # the tangent is symmetric (hyperelastic and QLV stresses from one energy's tangent, springs,
    # the punch row and column fixed together): the solver factorizes it as such
    # (tests/test_forward.py checks it under both controls)
    symmetric_tangent = True

    def __init__(self, space: Space, params: dict, punch="frictionless", support="fixed"):
        fixed, tied = constrained_components(space.mesh, punch, support)
        self.space, self.punch, self.support = space, punch, support
        self.footprint = space.mesh.nodes("footprint")
        index, sign, n_free = displacement_numbering(fixed, tied)
        self.n_free = n_free
        self.punch_index = n_free
        self.n_red = n_free + 1
        self.asm = ReducedAssembler(space.edofs, index, sign, self.n_red)
        self.punch_spring, self.bottom_spring = face_springs(space.mesh, self.asm, punch, support)
        self.set_params(params)

    # -- material ----------------------------------------------------------------------
    def set_params(self, params: dict):
        """Set material parameters (scalars or per-element arrays)."""
        ne = self.space.mesh.n_elements
        def col(v):
            v = np.asarray(v, dtype=float)
            return v.reshape(ne, 1) if v.ndim == 1 else v
        self.params = dict(params)
        p = {k: col(v) for k, v in params.items() if k in ("C1", "C2", "D1", "D2", "g1", "tau_g1", "k1", "tau_k1")}
        self._C1, self._C2, self._D1 = p["C1"], p["C2"], p["D1"]
        D2 = p.get("D2", np.inf)
        self._D2inv = np.where(np.isinf(D2), 0.0, 1.0 / np.where(np.isinf(D2), 1.0, D2))
        self._g1, self._tau_g1 = p.get("g1", 0.0), p.get("tau_g1", 1.0)
        self._k1, self._tau_k1 = p.get("k1", 0.0), p.get("tau_k1", 1.0)
        self.viscous = bool(np.any(self._g1 > 0) or np.any(self._k1 > 0))
        self.k_punch, self.k_bottom = spring_stiffnesses(params, self.punch_spring, self.support)

    def with_params(self, params: dict) -> "Indentation":
        """A copy with other parameters, sharing the space and assembler."""
        import copy
        new = copy.copy(self)
        new.set_params(params)
        return new

    def new_state(self) -> QLVState:
        return QLVState(self.space.dV.shape)

    # -- kinematics --------------------------------------------------------------------
    def displacement(self, q) -> np.ndarray:
        """(n_nodes, 3) nodal displacement of reduced unknowns q."""
        return self.asm.expand(q).reshape(-1, 3)

    def kinematics(self, q) -> Kinematics:
        """`Kinematics` at q, remembered for the last q: the models made by `with_params` share
        the memory (and the space), so the variants of a sensitivity step evaluated at one q
        compute F and its invariants once."""
        memo = self.space.__dict__.get("_kinematics_memo")   # (assembler, q, kinematics)
        if memo is not None and memo[0] is self.asm and memo[1].shape == np.shape(q) and np.array_equal(memo[1], q):
            return memo[2]
        kin = Kinematics(self.space.deformation_gradient(self.displacement(q)))
        self.space._kinematics_memo = (self.asm, np.array(q, dtype=float, copy=True), kin)
        return kin

    # -- residual and tangent ------------------------------------------------------------
    def evaluate(self, q, dt, state: QLVState, tangent=True) -> Evaluation:
        """Reduced internal force and tangent at q, for a step of length dt from `state`."""
        sp = self.space
        kin = self.kinematics(q)
        F = kin.F
        S_iso, S_vol, terms, J = hyperelastic_terms(kin, self._C1, self._C2, self._D1, self._D2inv)
        S, a_g, a_k = self._relaxed_stress(S_iso, S_vol, dt, state)
        r = self.asm.vector(sp.internal_force(F, S)) + self.spring_force(q)
        springs = self._springs()
        K = None
        if tangent:
            Ke = element_stiffness(sp.dNdX, sp.dV, F, S, terms, a_g, a_k)
            K = self.asm.matrix(Ke)
            for f, k in springs:
                f.add_tangent(K, k)
        return Evaluation(r, K, S_iso, S_vol, float(J.min()))

    def linearized_directions(self, variants, eps, is_force):
        """The batched, linearized sensitivity step along `variants` (`linearized`)."""
        from .linearized import LinearizedDirections
        return LinearizedDirections(self, variants, eps, is_force)

    def residual_change(self, other: "Indentation", q) -> np.ndarray | None:
        """other's residual minus this model's at q, assembled from the elements whose
        parameters differ only (an inclusion's sphere): exact, at a small fraction of a
        residual evaluation. None where that does not hold or does not pay: a viscous model
        (its history enters every element's stress), other springs, or more than a quarter
        of the elements changed."""
        if self.viscous or other.viscous or (self.k_punch, self.k_bottom) != (other.k_punch, other.k_bottom):
            return None
        ne = self.space.mesh.n_elements
        mine, theirs = self._material(), other._material()
        changed = np.zeros(ne, bool)
        for a, b in zip(mine, theirs):
            changed |= np.broadcast_to(np.asarray(a != b), (ne, 1)).ravel()
        elements = np.flatnonzero(changed)
        if len(elements) > ne // 4:
            return None
        F = self.space.deformation_gradient(self.displacement(q), elements)
        fe = np.zeros((ne, 30))
        for sign, material in ((1.0, theirs), (-1.0, mine)):
            rows = [v[elements] if np.ndim(v) == 2 else v for v in material]
            S_iso, S_vol, _, _ = hyperelastic_terms(F, *rows)
            fe[elements] += sign * self.space.internal_force(F, S_iso + S_vol, elements)
        return self.asm.vector(fe)

    def _material(self):
        return self._C1, self._C2, self._D1, self._D2inv

    def _relaxed_stress(self, S_iso, S_vol, dt, st: QLVState):
        if not self.viscous:
            one = np.ones(S_iso.shape[:-2])
            return S_iso + S_vol, one, one
        return qlv_relaxed_stress(S_iso, S_vol, dt, st, self._g1, self._tau_g1, self._k1, self._tau_k1)

    def commit(self, state: QLVState, ev: Evaluation, dt) -> QLVState:
        """History after a converged step of length dt ending at evaluation `ev`."""
        if not self.viscous:
            return state
        return qlv_commit(state, ev.S0_iso, ev.S0_vol, dt, self._g1, self._tau_g1, self._k1, self._tau_k1)

    def state_after(self, state: QLVState, q, dt) -> QLVState:
        """The committed history of a step ending at q (`commit` without assembling the
        residual: only the elastic stresses at q are needed)."""
        if not self.viscous:
            return state
        S_iso, S_vol, _, J = hyperelastic_terms(self.kinematics(q), self._C1, self._C2, self._D1, self._D2inv)
        return self.commit(state, Evaluation(None, None, S_iso, S_vol, float(J.min())), dt)

    def fix_punch(self, K):
        """Make the punch depth a prescribed unknown in K (displacement control)."""
        return self.asm.fix(K, self.punch_index)
