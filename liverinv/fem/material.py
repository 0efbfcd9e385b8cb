r"""Constitutive kernels, vectorized over quadrature points (the kinematics and the element
stiffness compiled, `fem.kernels`).

Reduced polynomial strain energy (seed paper Eq. 9, Abaqus convention)::

    U = C1 (I1b - 3) + C2 (I1b - 3)^2 + (1/D1) (J - 1)^2 + (1/D2) (J - 1)^4,
    I1b = J^(-2/3) tr C

split into its isochoric and volumetric parts, each giving a second Piola-Kirchhoff stress
S0 = 2 dU/dC and a material tangent CC = 2 dS0/dC = 4 d2U/dCdC:

    S0_iso = 2 W' dI1b/dC,     dI1b/dC = J^(-2/3) (I - I1/3 C^-1)
    CC_iso = 4 (W'' dI1b/dC (x) dI1b/dC + W' d2I1b/dCdC)
    S0_vol = J p C^-1,         p = dU_vol/dJ
    CC_vol = J (p + J p') C^-1 (x) C^-1 - 2 J p C^-1 (.) C^-1

with (A (.) B)_IJKL = (A_IK B_JL + A_IL B_JK) / 2.

Quasi-linear viscoelasticity (Eqs. 10-11) relaxes each part with its one-term Prony series,
S = int G(t-s)/G0 dS0_iso/ds ds + int K(t-s)/K0 dS0_vol/ds ds. With
H(t) = int exp(-(t-s)/tau) dS0/ds ds the recursive update

    H_{n+1} = exp(-dt/tau) H_n + gamma (S0_{n+1} - S0_n),  gamma = (1 - exp(-dt/tau)) / (dt/tau)

is exact when S0 varies linearly over the step, so
S_{n+1} = (1 - g1 + g1 gamma) S0_iso,{n+1} + g1 (exp(-dt/tau) H_n - gamma S0_iso,n) + (same, bulk)
and the consistent tangent is (1 - g1 + g1 gamma) CC_iso + (1 - k1 + k1 gamma_k) CC_vol: symmetric.

Parameters are arrays broadcasting against the quadrature-point axes (ne, nq), so they may
vary by element (regions, inclusions).
"""

from __future__ import annotations

import numpy as np

from . import kernels

__all__ = ["Kinematics", "hyperelastic_split", "hyperelastic_terms", "element_stiffness", "full_tangents",
           "first_elasticity", "relaxation_factors", "QLVState"]

_I = np.eye(3)


def _outer(A, B):
    return A[..., :, :, None, None] * B[..., None, None, :, :]


def _sym_prod(A, B):
    """(A (.) B)_IJKL = (A_IK B_JL + A_IL B_JK) / 2."""
    return 0.5 * (A[..., :, None, :, None] * B[..., None, :, None, :]
                  + A[..., :, None, None, :] * B[..., None, :, :, None])


def _det(F):
    """Determinants of 3x3 matrices (..., 3, 3)."""
    return (F[..., 0, 0] * (F[..., 1, 1] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 1])
            - F[..., 0, 1] * (F[..., 1, 0] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 0])
            + F[..., 0, 2] * (F[..., 1, 0] * F[..., 2, 1] - F[..., 1, 1] * F[..., 2, 0]))


def hyperelastic_split(F, C1, C2, D1, D2inv=0.0, tangent=True):
    """Isochoric and volumetric PK2 stresses (and material tangents) of the reduced
    polynomial law at deformation gradients F (..., 3, 3).

    `D2inv` is 1/D2 (0 for no quartic volumetric term). Returns
    (S_iso, S_vol, CC_iso, CC_vol, J); the tangents are None when `tangent` is False.
    """
    S_iso, S_vol, terms, J = hyperelastic_terms(F, C1, C2, D1, D2inv)
    if not tangent:
        return S_iso, S_vol, None, None, J
    CC_iso, CC_vol = full_tangents(terms)
    return S_iso, S_vol, CC_iso, CC_vol, J


def tangent_terms(I1, Jm23, Wp, Wpp, J, p, dp, dI1b, Ci) -> dict:
    """The material tangents as scalar multiples of four tensor products, which is all the
    structured element stiffness needs:

        CC_iso = c_dd d(x)d + c_ICi (I(x)Ci + Ci(x)I) + c_CiCi_iso Ci(x)Ci + c_sym_iso Ci(.)Ci
        CC_vol = c_CiCi_vol Ci(x)Ci + c_sym_vol Ci(.)Ci,      d = dI1b/dC
    """
    return dict(d=dI1b, Ci=Ci, c_dd=4.0 * Wpp, c_ICi=-4.0 / 3.0 * Wp * Jm23,
                c_CiCi_iso=4.0 / 9.0 * Wp * Jm23 * I1, c_sym_iso=4.0 / 3.0 * Wp * Jm23 * I1,
                c_CiCi_vol=J * (p + J * dp), c_sym_vol=-2.0 * J * p)


def full_tangents(t: dict):
    """CC_iso and CC_vol as (..., 3, 3, 3, 3) arrays from `tangent_terms`."""
    Ci, d = t["Ci"], t["d"]
    I = np.broadcast_to(_I, Ci.shape)
    x = lambda c: np.asarray(c)[..., None, None, None, None]
    CiCi, CiodCi = _outer(Ci, Ci), _sym_prod(Ci, Ci)
    CC_iso = (x(t["c_dd"]) * _outer(d, d) + x(t["c_ICi"]) * (_outer(I, Ci) + _outer(Ci, I))
              + x(t["c_CiCi_iso"]) * CiCi + x(t["c_sym_iso"]) * CiodCi)
    CC_vol = x(t["c_CiCi_vol"]) * CiCi + x(t["c_sym_vol"]) * CiodCi
    return CC_iso, CC_vol


class Kinematics:
    """The material-independent quantities of F (..., 3, 3) that the stresses need: C^-1, J,
    I1, J^-2/3 and dI1b/dC. Computed once, they serve every parameter variant at the same
    motion (the sensitivity step evaluates tens of them)."""

    __slots__ = ("F", "Ci", "J", "I1", "Jm23", "dI1b")

    def __init__(self, F):
        self.F = F
        # signed J: an inverted point has J < 0 and gives NaN stresses (`fem.kernels`)
        self.Ci, self.J, self.I1, self.Jm23, self.dI1b = kernels.kinematics(F)


def hyperelastic_terms(F, C1, C2, D1, D2inv=0.0):
    """Stresses and structured tangent terms (see `tangent_terms`) at F (..., 3, 3), or at
    its `Kinematics`: returns (S_iso, S_vol, terms, J)."""
    k = F if isinstance(F, Kinematics) else Kinematics(F)
    Ci, J, I1, Jm23, dI1b = k.Ci, k.J, k.I1, k.Jm23, k.dI1b
    I1b = Jm23 * I1
    Wp = C1 + 2.0 * C2 * (I1b - 3.0)
    S_iso = 2.0 * Wp[..., None, None] * dI1b
    Jm1 = J - 1.0
    p = 2.0 / D1 * Jm1 + 4.0 * D2inv * Jm1**3
    S_vol = (J * p)[..., None, None] * Ci
    terms = tangent_terms(I1, Jm23, Wp, 2.0 * C2 * np.ones_like(I1b), J, p,
                          2.0 / D1 + 12.0 * D2inv * Jm1**2, dI1b, Ci)
    return S_iso, S_vol, terms, J


def element_stiffness(G, dV, F, S, t: dict, a_g, a_k):
    """Element tangent matrices (ne, 30, 30), dof order 3 a + i, of the total-Lagrangian
    model without forming 4th-order tensors: with v_X = G X F^T (10 x 3 per point),

        K = sum_q dV [ sum c v_X v_Y^T  +  c_sym/2 ((G Ci G^T) (x) (F Ci F^T)
                        + v_C v_C^T with i, k swapped)  +  (G S G^T) (x) I ]

    G (ne, nq, 10, 3) shape-function gradients, dV (ne, nq), a_g/a_k the relaxation
    factors multiplying the isochoric/volumetric tangents.
    """
    dV = np.asarray(dV, dtype=float)
    return kernels.element_stiffness(
        G, dV, F, S, t["d"], t["Ci"], a_g * t["c_dd"] * dV, a_g * t["c_ICi"] * dV,
        (a_g * t["c_CiCi_iso"] + a_k * t["c_CiCi_vol"]) * dV, 0.5 * (a_g * t["c_sym_iso"] + a_k * t["c_sym_vol"]) * dV)


def first_elasticity(F, S, CC):
    """P = F S and A = dP/dF, A_iJkL = F_iI CC_IJKL F_kK + delta_ik S_JL."""
    P = F @ S
    A = np.einsum("...iI,...IJKL,...kK->...iJkL", F, CC, F, optimize=True)
    A += _I[:, None, :, None] * S[..., None, :, None, :]
    return P, A


def relaxation_factors(dt, frac, tau):
    """(a, e, gamma) of the recursive update for one Prony term over a step dt:
    a = 1 - frac + frac gamma multiplies the instantaneous stress, e = exp(-dt/tau)."""
    x = np.asarray(dt / np.asarray(tau, dtype=float))
    e = np.exp(-x)
    with np.errstate(divide="ignore", invalid="ignore"):
        gamma = np.where(x > 1e-8, -np.expm1(-x) / np.where(x > 1e-8, x, 1.0), 1.0 - 0.5 * x)
    a = 1.0 - frac + frac * gamma
    return a, e, gamma


class QLVState:
    """History of the quasi-linear viscoelastic update at every quadrature point:
    H_iso, H_vol (the Prony integrals) and the instantaneous stresses of the last
    converged step."""

    def __init__(self, shape):
        z = np.zeros(shape + (3, 3))
        self.H_iso, self.H_vol, self.S0_iso, self.S0_vol = z, z.copy(), z.copy(), z.copy()

    def copy(self):
        new = QLVState.__new__(QLVState)
        new.H_iso, new.H_vol = self.H_iso.copy(), self.H_vol.copy()
        new.S0_iso, new.S0_vol = self.S0_iso.copy(), self.S0_vol.copy()
        return new


def qlv_relaxed_stress(S_iso, S_vol, dt, st: QLVState, g1, tau_g1, k1, tau_k1):
    """The QLV stress of a backward-Euler step dt from `st` (Prony term on the isochoric and
    on the volumetric stress, seed paper Eqs. 10-11) and the relaxation factors a_g, a_k of
    the instantaneous tangents."""
    a_g, e_g, c_g = relaxation_factors(dt, g1, tau_g1)
    a_k, e_k, c_k = relaxation_factors(dt, k1, tau_k1)
    a_g, a_k = np.broadcast_to(a_g, S_iso.shape[:-2]), np.broadcast_to(a_k, S_iso.shape[:-2])
    e = lambda x: np.broadcast_to(x, S_iso.shape[:-2])[..., None, None]
    S = (e(a_g) * S_iso + e(g1) * (e(e_g) * st.H_iso - e(c_g) * st.S0_iso)
         + e(a_k) * S_vol + e(k1) * (e(e_k) * st.H_vol - e(c_k) * st.S0_vol))
    return S, a_g, a_k


def qlv_commit(state: QLVState, S0_iso, S0_vol, dt, g1, tau_g1, k1, tau_k1) -> QLVState:
    """The QLV history after a converged step dt ending at instantaneous stresses S0."""
    new = QLVState.__new__(QLVState)
    _, e_g, c_g = relaxation_factors(dt, g1, tau_g1)
    _, e_k, c_k = relaxation_factors(dt, k1, tau_k1)
    b = lambda x: np.broadcast_to(x, S0_iso.shape[:-2])[..., None, None]
    new.H_iso = b(e_g) * state.H_iso + b(c_g) * (S0_iso - state.S0_iso)
    new.H_vol = b(e_k) * state.H_vol + b(c_k) * (S0_vol - state.S0_vol)
    new.S0_iso, new.S0_vol = S0_iso, S0_vol
    return new

