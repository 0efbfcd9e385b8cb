r"""Biphasic (poroelastic) indentation: a hyperelastic skeleton saturated by a Darcy fluid.

Mixture of intrinsically incompressible constituents (seed paper Eqs. 6-7), finite strain,
total-Lagrangian u-p form: quadratic displacement u and linear pore pressure p on the tet10
mesh (Taylor-Hood), pressure unknowns at the corner nodes, backward Euler in time.

Constitutive relations, with F = I + Grad u, J = det F, C = F^T F::

    P = F S_solid(C) - p J F^-T                 (sigma = sigma_solid - p I)
    w = -kappa grad p,   W = J F^-1 w = -kappa J C^-1 Grad p

S_solid is the reduced polynomial law (`material.hyperelastic_terms`); its D1 term acts on
the skeleton's J, so the mixture changes volume only by fluid exchange. kappa is the
spatial permeability (m^4/(N s)), constant and isotropic. With g1 or k1 > 0 the skeleton is
quasi-linear viscoelastic as in `indentation.Indentation` (Prony terms on its isochoric and
volumetric stress; the pore pressure is not relaxed).

Weak form at t_{n+1} (step dt, J_n = J at t_n), for all du and dp vanishing where u and p
are prescribed::

    R_u = int (F S_solid - p J F^-T) : Grad du dV - f_ext . du                      = 0
    R_p = -s int dp (J - J_n) dV - s dt int kappa J (C^-1 Grad p) . Grad dp dV   = 0

(mass balance J_dot + Div W = 0 times -dt s; no-flux faces are natural, p = 0 on the
draining faces). The factor -dt makes the u-p coupling blocks transposes of each other, and
the pressure unknown is the scaled p_hat = p / s, with s = mu0 / h (Pa/m, h a typical element
size) so that s R_p is a force commensurate with R_u in the solver's residual norm.

Linearization (spatial gradients g(.) = F^-T Grad(.), L = g(Delta u); N_a the tet10 and
N_b, N_c the P1 shape functions; K_up = dR_u/dp_hat, K_pu = d(R_p)/du)::

    K_uu = solid tangent with S = S_solid - p J C^-1, whose material tangent gains
           -p J (C^-1 (x) C^-1 - 2 C^-1 (.) C^-1)           (`material.element_stiffness`)
    K_up[a i, b] = -s int N_b J g(N_a)_i dV
    K_pu[b, a k] = K_up[a k, b] - s dt kappa int J [g(N_a)_k (g p . g N_b)
                   - (g p)_k (g N_a . g N_b) - (g N_b)_k (g N_a . g p)] dV
    K_pp[b, c]   = -s^2 dt kappa int J g N_b . g N_c dV

using d(J) = J tr L and d(g p . g q) = -g p . (L + L^T) g q. The only non-symmetric part is
the permeation term of K_pu (the flux depends on the deformation); it is kept (exact Newton).

Reduced unknowns: [free u dofs, punch depth d, free p dofs]; the punch entry of the residual
is the total indenter force (solid plus fluid), so `solver.solve_history` drives this model
unchanged. Boundary conditions: bottom fixed, sliding or compliant, frictionless (with the
tangential spring k_punch of partial friction) or bonded punch, side
free or laterally confined (u_x = u_y = 0), p = 0 on the `drained` groups.

Verification (tests/test_biphasic.py): Terzaghi consolidation, undrained incompressible and
drained elastic limits, fluid mass balance, finite-difference tangent, and the benchmark's
FEBio 4 poroelastic reference, reproduced to 2e-6 with FEBio's 8-point tet10 rule (the
engine's default 4-point rule gives F 0.5-0.8% lower on the coarse mesh).

Quadrature: use 8 points or more. With the 4-point rule the discrete volume constraint acts
on J at only 4 points per element and the tangent turns singular at the punch rim once the
response is close to undrained: the coarse mesh fails near 7.3-8 mm for kappa <= 1e-8
(Table 1 seed C1 150, C2 4000, D1 2e-4, kappa 1e-8) and the fine mesh near 9.18 mm at
kappa 1e-7; FEBio's 8-point (`febio8_space`) and the 14-point rule run all of these
without a step cut (the 8-point rule also down to kappa 1e-12).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from . import kernels
from .assembly import ReducedAssembler
from .boundary import constrained_components, displacement_numbering, face_springs
from .indentation import Evaluation, spring_stiffnesses
from .material import QLVState, _det, element_stiffness, hyperelastic_terms, qlv_commit, qlv_relaxed_stress
from .space import Space
from .springs import SpringTerms

__all__ = ["Biphasic", "BiphasicState", "BiphasicEvaluation", "DRAINED_DEFAULT", "febio8_space"]

log = logging.getLogger(__name__)

DRAINED_DEFAULT = ("side", "top_free")
_VTK_EDGES = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [1, 3], [2, 3]])


@dataclass
class BiphasicState:
    """J at every quadrature point at the end of the last converged step, and, for a
    quasi-linear viscoelastic skeleton, the Prony history of `material.QLVState`."""
    J_n: np.ndarray
    H_iso: np.ndarray = None
    H_vol: np.ndarray = None
    S0_iso: np.ndarray = None
    S0_vol: np.ndarray = None

    def copy(self):
        return BiphasicState(*(None if v is None else v.copy() for v in
                               (self.J_n, self.H_iso, self.H_vol, self.S0_iso, self.S0_vol)))


@dataclass
class BiphasicEvaluation(Evaluation):
    J: np.ndarray = None          # (ne, nq) volume ratio
    fe_p: np.ndarray = None       # (ne, 4) element mass residuals (scaled by s)


def febio8_space(mesh) -> Space:
    """Tet10 space on FEBio's 8-point rule (FETet10G8), the rule of the benchmark's FEBio
    poroelastic reference."""
    return Space(mesh, rule="febio8")


def pressure_shape(space: Space):
    """P1 shape functions (the barycentric coordinates of the corners) at the quadrature
    points, (nq, 4), and their reference gradients (ne, nq, 4, 3), written exactly in the
    tet10 basis: lambda_i = N_i + (N_m1 + N_m2) / 2 over the mid-edge nodes m of edges at i."""
    cells, conn = space.mesh.cells, space.conn
    if not np.array_equal(conn[:, :4], cells[:, :4]):
        raise RuntimeError("tet10 space does not keep the cells' corner order")
    # local mid dof a (4..9) -> which VTK edge of the cell it is -> its two local corners
    hit = conn[:, 4:, None] == cells[:, None, 4:]            # (ne, 6 local, 6 vtk)
    if not (hit.sum(-1) == 1).all():
        raise RuntimeError("mid-edge nodes of the space and the mesh do not match")
    vtk = hit.argmax(-1)                                      # (ne, 6)
    if not (vtk == vtk[0]).all():
        raise RuntimeError("local edge order varies between elements")
    c = np.zeros((4, 10))
    c[np.arange(4), np.arange(4)] = 1.0
    for a, e in enumerate(vtk[0]):
        c[_VTK_EDGES[e], 4 + a] = 0.5
    Np = space.N @ c.T
    dNp = np.einsum("ia,eqaj->eqij", c, space.dNdX, optimize=True)
    return Np, np.ascontiguousarray(dNp)


class Biphasic(SpringTerms):
    """Finite-strain biphasic indentation model (interface of `indentation.Indentation`).

    Parameters
    ----------
    space : Space
    params : dict with C1, C2, D1 (D2 optional), kappa: scalars or (ne,) arrays
    punch : "frictionless" or "bonded" (frictionless: k_punch, a tangential spring on the
        footprint, as in `indentation.Indentation`)
    support : "fixed", "sliding" or "compliant" (bottom; compliant: tangential spring of
        compliance c_bottom)
    side : "free" or "confined" (u_x = u_y = 0 on the `side` nodes: confined compression)
    drained : mesh groups with p = 0 (free draining); all other faces are impermeable
    pressure_scale : s in Pa/m (default mu0 / h, h = median cube root of element volume)

    Examples
    --------
    >>> model = Biphasic(Space(mesh), dict(C1=200, C2=5000, D1=1.5e-3, kappa=1e-7))
    >>> h = solve_history(model, t, d, "displacement", NewtonOptions(method="full"))
    """

    def __init__(self, space: Space, params: dict, punch="frictionless", support="fixed",
                 side="free", drained=DRAINED_DEFAULT, pressure_scale=None):
        fixed, tied = constrained_components(space.mesh, punch, support, side)
        self.space, self.punch, self.support, self.side = space, punch, support, side
        self.drained = tuple(drained)
        mesh = space.mesh
        n = mesh.n_nodes
        self.footprint = mesh.nodes("footprint")
        # pressure dofs: one per corner node, full numbering 3 n + corner id
        self.p_nodes = mesh.corner_nodes()
        corner_id = -np.ones(n, dtype=np.int64)
        corner_id[self.p_nodes] = np.arange(len(self.p_nodes))
        self.p_elem = corner_id[space.conn[:, :4]]                       # (ne, 4)
        dry = np.zeros(n, dtype=bool)
        for g in self.drained:
            dry[mesh.nodes(g)] = True
        p_free = ~dry[self.p_nodes]
        self.n_full = 3 * n + len(self.p_nodes)
        u_index, u_sign, n_free = displacement_numbering(fixed, tied)
        index = -np.ones(self.n_full, dtype=np.int64)
        index[:3 * n] = u_index
        index[3 * n:][p_free] = n_free + 1 + np.arange(int(p_free.sum()))
        sign = np.ones(self.n_full)
        sign[:3 * n] = u_sign
        self.n_free, self.punch_index = n_free, n_free
        self.n_red = n_free + 1 + int(p_free.sum())
        self.p_drained = ~p_free
        self.edofs = np.concatenate([space.edofs, 3 * n + self.p_elem], axis=1)   # (ne, 34)
        self.asm = ReducedAssembler(self.edofs, index, sign, self.n_red)
        self.Np, self.dNpdX = pressure_shape(space)
        # the tangential springs of `indentation` (friction, slip) act on the u dofs alone
        self.punch_spring, self.bottom_spring = face_springs(mesh, self.asm, punch, support)
        self._pressure_scale = pressure_scale
        self.set_params(params)
        log.debug("biphasic: %d u unknowns, %d free of %d pressure nodes, s = %.3g Pa/m",
                  n_free, int(p_free.sum()), len(self.p_nodes), self.s)

    # -- material ----------------------------------------------------------------------
    def set_params(self, params: dict):
        """Set C1, C2, D1, (D2), kappa: scalars or per-element arrays."""
        ne = self.space.mesh.n_elements
        col = lambda v: (lambda a: a.reshape(ne, 1) if a.ndim == 1 else a)(np.asarray(v, dtype=float))
        missing = [k for k in ("C1", "C2", "D1", "kappa") if k not in params]
        if missing:
            raise ValueError(f"biphasic model needs parameter(s) {missing}")
        self.params = dict(params)
        self._C1, self._C2, self._D1 = col(params["C1"]), col(params["C2"]), col(params["D1"])
        D2 = col(params.get("D2", np.inf))
        self._D2inv = np.where(np.isinf(D2), 0.0, 1.0 / np.where(np.isinf(D2), 1.0, D2))
        self._g1, self._tau_g1 = col(params.get("g1", 0.0)), col(params.get("tau_g1", 1.0))
        self._k1, self._tau_k1 = col(params.get("k1", 0.0)), col(params.get("tau_k1", 1.0))
        self.viscous = bool(np.any(self._g1 > 0) or np.any(self._k1 > 0))
        self.k_punch, self.k_bottom = spring_stiffnesses(params, self.punch_spring, self.support)
        self._kappa = col(params["kappa"])
        if np.any(~np.isfinite(self._kappa)) or np.any(self._kappa < 0):
            raise ValueError("kappa must be finite and >= 0")
        if self._pressure_scale is None:
            h = np.median(np.cbrt(self.space.dV.sum(axis=1)))
            self.s = float(2.0 * np.mean(self._C1) / h)
        else:
            self.s = float(self._pressure_scale)

    def with_params(self, params: dict) -> "Biphasic":
        """A copy with other parameters and the same pressure scale (so the same reduced
        unknowns mean the same pressures), sharing the space and assembler."""
        import copy
        new = copy.copy(self)
        new._pressure_scale = self.s
        new.set_params(params)
        return new

    def new_state(self) -> BiphasicState:
        shape = self.space.dV.shape
        q = QLVState(shape)      # carried also when elastic: a viscous variant (sensitivity) needs it
        return BiphasicState(np.ones(shape), q.H_iso, q.H_vol, q.S0_iso, q.S0_vol)

    # -- fields --------------------------------------------------------------------------
    def displacement(self, q) -> np.ndarray:
        """(n_nodes, 3) nodal displacement of reduced unknowns q."""
        return self.asm.expand(q)[: 3 * self.space.mesh.n_nodes].reshape(-1, 3)

    def pressure(self, q) -> np.ndarray:
        """Pore pressure (Pa) at the corner nodes `p_nodes`."""
        return self.s * self.asm.expand(q)[3 * self.space.mesh.n_nodes:]

    # -- residual and tangent ------------------------------------------------------------
    def evaluate(self, q, dt, state: BiphasicState, tangent=True) -> BiphasicEvaluation:
        """Reduced residual [R_u, indenter force, s R_p] and tangent at q for a step dt."""
        sp, s = self.space, self.s
        full = self.asm.expand(q)
        n3 = 3 * sp.mesh.n_nodes
        F = sp.deformation_gradient(full[:n3].reshape(-1, 3))
        S_iso, S_vol, t, J = hyperelastic_terms(F, self._C1, self._C2, self._D1, self._D2inv)
        pe = s * full[n3:][self.p_elem]                                    # (ne, 4)
        Ci = t["Ci"]
        kdt = self._kappa * dt * J * sp.dV                                 # (ne, nq)
        p, Gp, fe_p = kernels.darcy_terms(pe, self.Np, self.dNpdX, J, state.J_n, sp.dV, kdt, Ci, s)
        Jp = J * p
        if self.viscous:
            S_solid, a_g, a_k = qlv_relaxed_stress(S_iso, S_vol, dt, state, self._g1, self._tau_g1,
                                                   self._k1, self._tau_k1)
        else:
            S_solid, a_g, a_k = S_iso + S_vol, 1.0, 1.0
        S = S_solid - Jp[..., None, None] * Ci
        fe_u = sp.internal_force(F, S)
        r = self.asm.vector(np.concatenate([fe_u, fe_p], axis=1)) + self.spring_force(q)
        K = None
        if tangent:
            K = self.asm.matrix(self._element_tangent(F, S, t, J, p, Gp, Ci, kdt, a_g, a_k))
            for f, k in self._springs():
                f.add_tangent(K, k)
        return BiphasicEvaluation(r, K, S_iso, S_vol, float(J.min()), J=J, fe_p=fe_p)

    def _element_tangent(self, F, S, t, J, p, Gp, Ci, kdt, a_g=1.0, a_k=1.0):
        sp, s = self.space, self.s
        ne = len(F)
        # the pressure terms ride in the volumetric slot, which element_stiffness multiplies
        # by the bulk relaxation factor a_k (> 0): divide them by it
        t = dict(t, c_CiCi_vol=t["c_CiCi_vol"] - J * p / a_k, c_sym_vol=t["c_sym_vol"] + 2.0 * J * p / a_k)
        Ke = np.empty((ne, 34, 34))
        Ke[:, :30, :30] = element_stiffness(sp.dNdX, sp.dV, F, S, t, a_g, a_k)
        Finv = Ci @ np.swapaxes(F, -1, -2)
        nq = sp.nq
        gN = (sp.dNdX @ Finv).reshape(ne, nq, 30)            # spatial gradients, (a, i) flat
        gNp = self.dNpdX @ Finv                               # (ne, nq, 4, 3)
        gp = (Gp[..., None, :] @ Finv)[..., 0, :]             # (ne, nq, 3)
        mT = lambda A: np.swapaxes(A, -1, -2)
        Kup = -s * (mT(gN) @ ((J * sp.dV)[..., None] * self.Np))            # (ne, 30, 4)
        Ke[:, :30, 30:] = Kup
        c = (-s * kdt)[..., None]                             # s R_p permeation: -s dt kappa J dV
        gN3 = gN.reshape(ne, nq, 10, 3)
        gp_gNp = (gNp @ gp[..., None])[..., 0]                # (ne, nq, 4)
        gN_gp = (gN3 @ gp[..., None])[..., 0]                 # (ne, nq, 10)
        gN_gNp = gN3 @ mT(gNp)                                # (ne, nq, 10, 4)
        T1 = mT(c * gp_gNp) @ gN                              # [b, (a k)]
        T2 = mT((c * gN_gNp.reshape(ne, nq, 40))) @ gp        # [(a b), k]
        T3 = mT((c * gNp.reshape(ne, nq, 12))) @ gN_gp        # [(b k), a]
        Kperm = (T1 - T2.reshape(ne, 10, 4, 3).transpose(0, 2, 1, 3).reshape(ne, 4, 30)
                 - T3.reshape(ne, 4, 3, 10).transpose(0, 1, 3, 2).reshape(ne, 4, 30))
        Ke[:, 30:, :30] = mT(Kup) + Kperm
        G = gNp.transpose(0, 2, 1, 3).reshape(ne, 4, nq * 3)
        Ke[:, 30:, 30:] = s * ((G * np.repeat(c[..., 0], 3, axis=1)[:, None]) @ mT(G))
        return Ke

    def commit(self, state: BiphasicState, ev: BiphasicEvaluation, dt) -> BiphasicState:
        """History after a converged step: J_n <- J (and the Prony history)."""
        return self._committed(state, ev.J.copy(), ev.S0_iso, ev.S0_vol, dt)

    def _committed(self, state, J, S0_iso, S0_vol, dt):
        if not self.viscous:
            return BiphasicState(J, state.H_iso, state.H_vol, state.S0_iso, state.S0_vol)
        h = qlv_commit(state, S0_iso, S0_vol, dt, self._g1, self._tau_g1, self._k1, self._tau_k1)
        return BiphasicState(J, h.H_iso, h.H_vol, h.S0_iso, h.S0_vol)

    def state_after(self, state: BiphasicState, q, dt) -> BiphasicState:
        """The committed history of a step ending at q (`commit` without a residual
        evaluation: J, and the elastic stresses of a viscous skeleton, from the deformation
        gradient only)."""
        F = self.space.deformation_gradient(self.displacement(q))
        if not self.viscous:
            return BiphasicState(_det(F), state.H_iso, state.H_vol, state.S0_iso, state.S0_vol)
        S_iso, S_vol, _, J = hyperelastic_terms(F, self._C1, self._C2, self._D1, self._D2inv)
        return self._committed(state, J, S_iso, S_vol, dt)

    def fix_punch(self, K):
        """Make the punch depth a prescribed unknown in K (displacement control)."""
        return self.asm.fix(K, self.punch_index)

    # -- diagnostics ---------------------------------------------------------------------
    def drained_outflow(self, ev: BiphasicEvaluation) -> float:
        """Fluid volume (m^3) leaving through the draining faces during the step that ended
        at `ev`: minus the sum of the mass residuals of the drained pressure nodes (their
        'reaction fluxes'); the free nodes' residuals vanish at convergence."""
        Rp = np.bincount(self.p_elem.ravel(), weights=ev.fe_p.ravel(), minlength=len(self.p_nodes))
        return float(Rp[self.p_drained].sum() / self.s)

    def volume_change(self, ev: BiphasicEvaluation) -> float:
        """V - V0 (m^3) of the body at `ev`, int (J - 1) dV."""
        return float(((ev.J - 1.0) * self.space.dV).sum())

    def fluid_force(self, q) -> float:
        """Vertical force (N, compressive positive) of the pore pressure on the punch:
        int p da_z over the deformed footprint (3-point edge-midpoint rule, exact here)."""
        mesh = self.space.mesh
        tri = mesh.facets["footprint"]
        x = mesh.points[tri] + self.displacement(q)[tri]          # (nf, 6, 3)
        pn = np.zeros(mesh.n_nodes)
        pn[self.p_nodes] = self.pressure(q)
        pc = pn[tri[:, :3]]
        out = 0.0
        for xi, eta in ((0.5, 0.0), (0.5, 0.5), (0.0, 0.5)):
            dN = _tri6_grad(xi, eta)                              # (6, 2)
            a = np.einsum("fnk,nd->fdk", x, dN)
            A0 = np.einsum("fnk,nd->fdk", mesh.points[tri], dN)
            jz = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
            jz0 = A0[:, 0, 0] * A0[:, 1, 1] - A0[:, 0, 1] * A0[:, 1, 0]
            pq = pc @ np.array([1 - xi - eta, xi, eta])
            out += (pq * jz * np.sign(jz0)).sum() / 6.0
        return float(out)


def _tri6_grad(xi, eta):
    """Gradients (6, 2) of the triangle6 shape functions (corners, then mid 01, 12, 20)."""
    l0 = 1 - xi - eta
    return np.array([[1 - 4 * l0, 1 - 4 * l0], [4 * xi - 1, 0.0], [0.0, 4 * eta - 1],
                     [4 * (l0 - xi), -4 * xi], [4 * eta, 4 * xi], [-4 * eta, 4 * (l0 - eta)]])
