r"""Constitutive kernels, vectorized over quadrature points.

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

__all__ = ["hyperelastic_split", "first_elasticity", "relaxation_factors", "QLVState"]

_I = np.eye(3)


def _outer(A, B):
    return A[..., :, :, None, None] * B[..., None, None, :, :]


def _sym_prod(A, B):
    """(A (.) B)_IJKL = (A_IK B_JL + A_IL B_JK) / 2."""
    return 0.5 * (A[..., :, None, :, None] * B[..., None, :, None, :]
                  + A[..., :, None, None, :] * B[..., None, :, :, None])


def hyperelastic_split(F, C1, C2, D1, D2inv=0.0, tangent=True):
    """Isochoric and volumetric PK2 stresses (and material tangents) of the reduced
    polynomial law at deformation gradients F (..., 3, 3).

    `D2inv` is 1/D2 (0 for no quartic volumetric term). Returns
    (S_iso, S_vol, CC_iso, CC_vol, J); the tangents are None when `tangent` is False.
    """
    C = np.einsum("...kI,...kJ->...IJ", F, F)
    J = np.linalg.det(F)
    Ci = np.linalg.inv(C)
    I1 = np.trace(C, axis1=-2, axis2=-1)
    Jm23 = J ** (-2.0 / 3.0)
    I1b = Jm23 * I1
    Wp = C1 + 2.0 * C2 * (I1b - 3.0)
    dI1b = Jm23[..., None, None] * (_I - (I1 / 3.0)[..., None, None] * Ci)
    S_iso = 2.0 * Wp[..., None, None] * dI1b
    Jm1 = J - 1.0
    p = 2.0 / D1 * Jm1 + 4.0 * D2inv * Jm1**3
    S_vol = (J * p)[..., None, None] * Ci
    if not tangent:
        return S_iso, S_vol, None, None, J
    Wpp = 2.0 * C2 * np.ones_like(I1b)
    CiCi = _outer(Ci, Ci)
    CiodCi = _sym_prod(Ci, Ci)
    d2I1b = Jm23[..., None, None, None, None] * (
        -1.0 / 3.0 * (_outer(np.broadcast_to(_I, Ci.shape), Ci) + _outer(Ci, np.broadcast_to(_I, Ci.shape)))
        + (I1 / 9.0)[..., None, None, None, None] * CiCi
        + (I1 / 3.0)[..., None, None, None, None] * CiodCi)
    CC_iso = 4.0 * (Wpp[..., None, None, None, None] * _outer(dI1b, dI1b)
                    + Wp[..., None, None, None, None] * d2I1b)
    dp = 2.0 / D1 + 12.0 * D2inv * Jm1**2
    CC_vol = (J * (p + J * dp))[..., None, None, None, None] * CiCi \
        - (2.0 * J * p)[..., None, None, None, None] * CiodCi
    return S_iso, S_vol, CC_iso, CC_vol, J


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
