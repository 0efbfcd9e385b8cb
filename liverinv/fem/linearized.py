r"""The sensitivity step of the indentation model along many directions at once, linearized.

`sensitivity.Sensitivity` differentiates a load history step by step: a right-hand side per
direction (the residual's change along the direction at the converged state, history
included), one block back-substitution, then the committed history's change. Its generic
form gets both by finite differences of the model's own `evaluate` and `state_after`, one
constitutive evaluation (and, for the history, one deformation gradient) per direction and
step: with the diagnosis's ~46 directions, most of its time. For `Indentation` every term
is linear in what changes, so here all directions are done together as array operations:

* the QLV stress of a step (seed paper Eqs. 10-11), per Prony branch (isochoric, volumetric),
  is ``S = a S0 + g (e H - c S0_prev)`` and its history update ``H' = e H + c (S0 - S0_prev)``,
  ``S0_prev' = S0`` (a, e, c the relaxation factors of the branch's g and tau over the step;
  an elastic model keeps its history unchanged). Along direction i, with its own factors
  (a_i, e_i, c_i) and state derivative (dH_i, dS0_prev_i)::

      dS_i = [(a_i - a) S0 + (g_i e_i - g e) H - (g_i c_i - g c) S0_prev] / eps
             + a_i dS0_theta_i + g_i (e_i dH_i - c_i dS0_prev_i)

  with ``dS0_theta_i`` the instantaneous stress's change with the direction's elastic
  parameters at the converged F (on the elements they change only: an inclusion's sphere);
  the right-hand side is ``-int F dS_i : Grad dv dV``;
* after the solve, the instantaneous stress moves by ``dS0_i = dS0_theta_i + CC : dE_i``,
  ``dE_i = sym(F^T Grad s_i)``: one 18 x 9 matrix per quadrature point maps Grad s_i to both
  parts (`stress_operator`), applied to all directions as a batched matrix product, and the
  branch's history derivative follows from the same linear update. The 1/eps terms are those
  of the generic form: a direction that opens a Prony branch (g from 0) or moves its
  relaxation time carries the branch's own history.

Boundary directions (the tangential springs' stiffness) change the springs' force only, and
force directions (`darcy.DrainedDarcy`) are the model itself plus a force; their history is
the model's, linearized the same way. Equal to the generic form to the finite-difference
step (tests/test_linearized.py); the generic form stays for models without this (Biphasic).

Batched arrays hold the directions last: tensors (ne, nq, 3, 3, k), factors (ne, 1, 1, 1, k).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .material import Kinematics, full_tangents, hyperelastic_terms, relaxation_factors

__all__ = ["LinearizedDirections", "stress_operator"]

_PARAMS = ("C1", "C2", "D1", "D2inv")
_VISCOUS = ("g1", "tau_g1", "k1", "tau_k1")


def _per_element(v, ne):
    """A parameter (a scalar or one value per element) as an (ne, 1) array."""
    v = np.asarray(v, dtype=float)
    return np.broadcast_to(v.reshape(-1, 1) if v.size == ne else v.reshape(1, 1), (ne, 1))


def _restricted(kin: Kinematics, elements) -> Kinematics:
    sub = Kinematics.__new__(Kinematics)
    for name in Kinematics.__slots__:
        setattr(sub, name, getattr(kin, name)[elements])
    return sub


def stress_operator(terms: dict, F) -> np.ndarray:
    """(..., 18, 9): the instantaneous stresses' change [dS0_iso; dS0_vol] (row-major 3 x 3
    each) for a change dF of F (row-major), dS0 = CC : sym(F^T dF) = CC_IJKL F_mK dF_mL
    (CC has the minor symmetries), from the tangent terms of `material.hyperelastic_terms`."""
    ops = [np.einsum("...IJKL,...mK->...IJmL", CC, F, optimize=True) for CC in full_tangents(terms)]
    return np.concatenate([A.reshape(A.shape[:-4] + (9, 9)) for A in ops], axis=-2)


class _Branch:
    """One Prony branch (isochoric: H_iso, S0_iso; volumetric: H_vol, S0_vol) over the
    directions whose stress it enters (all where the model has it, else those with g_i != 0
    somewhere)."""

    def __init__(self, name, g, tau, viscous, g_base, tau_base, viscous_base):
        self.name = name
        self.dirs = (np.arange(g.shape[-1]) if np.any(g_base != 0)
                     else np.flatnonzero(np.any(g != 0, axis=(0, 1, 2, 3))))
        d = self.dirs
        self.g, self.tau, self.viscous = g[..., d], tau[..., d], viscous[d]
        self.g_base, self.tau_base, self.viscous_base = g_base, tau_base, viscous_base
        # the directions that move the branch's own factors (g or tau): the 1/eps terms
        self.moved = np.flatnonzero(np.any((self.g != g_base) | (self.tau != tau_base), axis=(0, 1, 2, 3))
                                    | (self.viscous != viscous_base))
        self.dH = self.dS0 = None

    def start(self, shape):
        self.dH = np.zeros(shape + (3, 3, len(self.dirs)))
        self.dS0 = np.zeros_like(self.dH)

    def stress(self, dt, H, S0_prev, S0, eps):
        """The branch's dS_i without the elastic parameters' part, (ne, nq, 3, 3, len(dirs)),
        and a_i (ne, 1, 1, 1, len(dirs)) for that part."""
        a, e, c = relaxation_factors(dt, self.g, self.tau)
        a0, e0, c0 = relaxation_factors(dt, self.g_base, self.tau_base)
        out = self.g * e * self.dH - self.g * c * self.dS0
        m = self.moved
        if len(m):
            g = self.g[..., m]
            out[..., m] += ((a[..., m] - a0) / eps * S0[..., None] + (g * e[..., m] - self.g_base * e0) / eps * H[..., None]
                            - (g * c[..., m] - self.g_base * c0) / eps * S0_prev[..., None])
        return out, a

    def commit(self, dt, H, S0_prev, S0, dS0_new, eps):
        """The history derivatives after the step; dS0_new (ne, nq, 3, 3, len(dirs)) the
        instantaneous stress's derivative at its end."""
        _, e, c = relaxation_factors(dt, self.g, self.tau)
        _, e0, c0 = relaxation_factors(dt, self.g_base, self.tau_base)
        # a viscous model updates H <- e H + c (S0 - S0_prev), S0_prev <- S0; an elastic one keeps
        v = self.viscous
        ec, cc, sc = np.where(v, e, 1.0), np.where(v, c, 0.0), v.astype(float)
        ec0, cc0, sc0 = (e0, c0, 1.0) if self.viscous_base else (1.0, 0.0, 0.0)
        kept = None if v.all() else self.dS0.copy()       # an elastic direction keeps its dS0_prev
        dH = np.subtract(dS0_new, self.dS0, out=self.dS0)
        dH *= cc
        dH += ec * self.dH
        dS0 = dS0_new if kept is None else sc * dS0_new + (1.0 - sc) * kept
        m = self.moved
        if len(m):
            dH[..., m] += (ec[..., m] - ec0) / eps * H[..., None] + (cc[..., m] - cc0) / eps * (S0 - S0_prev)[..., None]
            dS0[..., m] += (sc[m] - sc0) / eps * (S0 - S0_prev)[..., None]
        self.dH, self.dS0 = dH, dS0


class LinearizedDirections:
    """The right-hand sides and history derivatives of an `Indentation` model's sensitivity
    step along `variants` (see module doc). A variant is a copy of the model with other
    material parameters (`with_params`), or other spring stiffnesses, or a force direction
    (`is_force`; its force is added by the caller)."""

    def __init__(self, model, variants, eps: float, is_force):
        self.model, self.eps = model, float(eps)
        ne = model.space.mesh.n_elements
        self.k = len(variants)
        self.springs = []       # (direction, variant) whose spring stiffnesses differ
        self.elastic = []       # (direction, its elements or None for all, its parameters there)
        base = self._material(model, ne)
        visc = {n: [] for n in _VISCOUS}
        viscous = np.zeros(self.k, bool)
        for i, var in enumerate(variants):
            if is_force(var):
                var = model
            mat = self._material(var, ne)
            changed = np.zeros(ne, bool)
            for n in _PARAMS:
                changed |= (mat[n] != base[n]).ravel()
            if (var.k_punch, var.k_bottom) != (model.k_punch, model.k_bottom):
                if changed.any() or any(np.any(mat[n] != base[n]) for n in _VISCOUS):
                    raise ValueError("a sensitivity direction may move the material or a spring, not both")
                self.springs.append((i, var))
            if changed.any():
                el = np.flatnonzero(changed)
                whole = len(el) == ne
                self.elastic.append((i, None if whole else el, {n: mat[n] if whole else mat[n][el] for n in _PARAMS}))
            for n in _VISCOUS:
                visc[n].append(mat[n])
            viscous[i] = var.viscous
        # (k, ne, 1) -> (ne, 1, 1, 1, k); the model's own (ne, 1) -> (ne, 1, 1, 1, 1)
        st = {n: np.stack(v, axis=-1).reshape(ne, 1, 1, 1, self.k) for n, v in visc.items()}
        b = {n: base[n].reshape(ne, 1, 1, 1, 1) for n in _VISCOUS}
        self.branches = [br for br in (
            _Branch("iso", st["g1"], st["tau_g1"], viscous, b["g1"], b["tau_g1"], model.viscous),
            _Branch("vol", st["k1"], st["tau_k1"], viscous, b["k1"], b["tau_k1"], model.viscous))
            if len(br.dirs)]
        # the reduced assembly of batched element vectors: one sparse product
        asm = model.asm
        m = asm._vec_mask.ravel()
        self._assemble = sp.csr_matrix((asm._vec_sign, (asm._vec_idx, np.flatnonzero(m))), shape=(asm.n_red, m.size))
        sp_ = model.space
        ne, nq = sp_.dV.shape
        # Grad of a nodal field as one (nq * 3, 10) matrix per element: rows (q, L), columns a
        self._grad = np.ascontiguousarray(sp_.dNdX.transpose(0, 1, 3, 2).reshape(ne, nq * 3, 10))
        self._dS0_theta = {}

    @staticmethod
    def _material(model, ne):
        p = dict(zip(_PARAMS, model._material()))
        p.update(g1=model._g1, tau_g1=model._tau_g1, k1=model._k1, tau_k1=model._tau_k1)
        return {n: np.array(_per_element(v, ne)) for n, v in p.items()}

    def start(self):
        shape = self.model.space.dV.shape
        for b in self.branches:
            b.start(shape)

    def _internal_force(self, F, dS):
        """Reduced internal forces (n_red, k) of the stress changes dS (ne, nq, 3, 3, k)."""
        ne, nq, _, _, k = dS.shape
        P = (F @ dS.reshape(ne, nq, 3, 3 * k)).reshape(ne, nq, 3, 3, k)      # P_iJ = F_iI dS_IJ
        Pt = P.transpose(0, 1, 3, 2, 4).reshape(ne, nq * 3, 3 * k)           # rows (q, J), cols (i, k)
        fe = (self.model.space._GdV_flat @ Pt).reshape(ne * 30, k)
        return self._assemble @ fe

    def rhs(self, q, dt, state, ev) -> np.ndarray:
        """-dR_i at the converged q of the step (history and parameters), (n_red, k)."""
        m, eps = self.model, self.eps
        kin = m.kinematics(q)
        dS = np.zeros(kin.J.shape + (3, 3, self.k))
        parts = {"iso": (state.H_iso, state.S0_iso, ev.S0_iso), "vol": (state.H_vol, state.S0_vol, ev.S0_vol)}
        a_of = {}
        for b in self.branches:
            s, a = b.stress(dt, *parts[b.name], eps)
            if len(b.dirs) == self.k:
                dS += s
            else:
                dS[..., b.dirs] += s
            a_of[b.name] = {int(d): a[..., j] for j, d in enumerate(b.dirs)}
        # the elastic parameters' change of the instantaneous stresses, on their elements
        self._dS0_theta = {}
        for i, el, p in self.elastic:
            sub = kin if el is None else _restricted(kin, el)
            S_iso, S_vol, _, _ = hyperelastic_terms(sub, p["C1"], p["C2"], p["D1"], p["D2inv"])
            sel = slice(None) if el is None else el
            d_iso, d_vol = (S_iso - ev.S0_iso[sel]) / eps, (S_vol - ev.S0_vol[sel]) / eps
            self._dS0_theta[i] = (el, d_iso, d_vol)
            for name, dd in (("iso", d_iso), ("vol", d_vol)):
                a = a_of.get(name, {}).get(i)
                if a is not None:
                    dd = (a if el is None else a[el]) * dd
                if el is None:
                    dS[..., i] += dd
                else:
                    dS[el, :, :, :, i] += dd
        r = -self._internal_force(kin.F, dS)
        for i, var in self.springs:
            r[:, i] -= (var.spring_force(q) - m.spring_force(q)) / eps
        return r

    def commit(self, q, dt, state, S):
        """Advance the history derivatives over the converged step ending at q, with the
        solution's derivatives S (n_red, k)."""
        if not self.branches:
            return
        m = self.model
        kin = m.kinematics(q)
        ne, nq = kin.J.shape
        dirs = np.unique(np.concatenate([b.dirs for b in self.branches]))
        kd = len(dirs)
        u = m.asm.expand(S[:, dirs]).reshape(-1, 3 * kd)                 # (n_nodes, (m, k))
        ue = u[m.space.conn]                                              # (ne, 10, 3 kd)
        dF = (self._grad @ ue).reshape(ne, nq, 3, 3, kd).transpose(0, 1, 3, 2, 4)   # (ne, nq, m, L, k)
        S_iso, S_vol, terms, _ = hyperelastic_terms(kin, *m._material())
        A = stress_operator(terms, kin.F).reshape(ne * nq, 18, 9)
        dS0 = (A @ dF.reshape(ne * nq, 9, kd)).reshape(ne, nq, 2, 3, 3, kd)
        pos = {int(d): j for j, d in enumerate(dirs)}
        parts = {"iso": (state.H_iso, state.S0_iso, S_iso, 0), "vol": (state.H_vol, state.S0_vol, S_vol, 1)}
        for b in self.branches:
            H, S0p, S0, part = parts[b.name]
            dS0_new = dS0[:, :, part][..., [pos[int(d)] for d in b.dirs]]
            for j, d in enumerate(b.dirs.tolist()):
                if d in self._dS0_theta:
                    el, d_iso, d_vol = self._dS0_theta[d]
                    dd = d_iso if b.name == "iso" else d_vol
                    if el is None:
                        dS0_new[..., j] += dd
                    else:
                        dS0_new[el, :, :, :, j] += dd
            b.commit(dt, H, S0p, S0, dS0_new, self.eps)
