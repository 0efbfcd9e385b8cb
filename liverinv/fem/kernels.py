"""Compiled constitutive and element kernels (numba), where numpy's batched 3 x 3 algebra
spends its time in dispatch and temporaries rather than arithmetic.

`kinematics` returns C^-1, J, I1, J^-2/3 and dI1b/dC of every deformation gradient in one
pass (`material.Kinematics`). `element_stiffness` forms the total-Lagrangian element tangents
(ne, 30, 30) of `material.element_stiffness`'s structured form point by point, one symmetric
3 x 3 node block at a time, and mirrors the lower triangle (every one of its terms is
symmetric in (a i) <-> (b k)). `deformation_gradient` and `internal_force` are `Space`'s;
`darcy_terms` the biphasic model's pore pressure, its gradient and mass residual.

Profiled on a 100-frame PSR solve with six parameter sensitivities on the medium model mesh
of the benchmark cylinder (2102 elements, 8 points each; session 42): numpy's element
stiffness took 160 ms a call (17.4 of 80 s) and the kinematics 6.7 ms (11.3 s). With these
kernels that solve takes 47-51 s, a plain solve 12.3 s (18 s), the same Phi to 1e-14
relative. Compiled on first use and cached on disk; they release the GIL.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["kinematics", "element_stiffness", "deformation_gradient", "internal_force", "darcy_terms"]


@numba.njit(cache=True, nogil=True)
def _kinematics(F, Ci, J, I1, Jm23, dI1b):
    for n in range(F.shape[0]):
        f = F[n]
        a = f[0, 0] * f[0, 0] + f[1, 0] * f[1, 0] + f[2, 0] * f[2, 0]      # C = F^T F
        b = f[0, 1] * f[0, 1] + f[1, 1] * f[1, 1] + f[2, 1] * f[2, 1]
        c = f[0, 2] * f[0, 2] + f[1, 2] * f[1, 2] + f[2, 2] * f[2, 2]
        d = f[0, 0] * f[0, 1] + f[1, 0] * f[1, 1] + f[2, 0] * f[2, 1]
        e = f[0, 1] * f[0, 2] + f[1, 1] * f[1, 2] + f[2, 1] * f[2, 2]
        g = f[0, 0] * f[0, 2] + f[1, 0] * f[1, 2] + f[2, 0] * f[2, 2]
        A = b * c - e * e
        B = g * e - d * c
        Cc = d * e - b * g
        D = a * c - g * g
        E = d * g - a * e
        G = a * b - d * d
        det = a * A + d * B + g * Cc
        ci = Ci[n]
        ci[0, 0], ci[1, 1], ci[2, 2] = A / det, D / det, G / det
        ci[0, 1] = ci[1, 0] = B / det
        ci[0, 2] = ci[2, 0] = Cc / det
        ci[1, 2] = ci[2, 1] = E / det
        j = (f[0, 0] * (f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1])
             - f[0, 1] * (f[1, 0] * f[2, 2] - f[1, 2] * f[2, 0])
             + f[0, 2] * (f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0]))
        J[n] = j
        tr = a + b + c
        I1[n] = tr
        jm = j ** (-2.0 / 3.0) if j > 0.0 else np.nan     # an inverted point: NaN stresses
        Jm23[n] = jm
        for r in range(3):
            for s in range(3):
                dI1b[n, r, s] = jm * ((1.0 if r == s else 0.0) - tr / 3.0 * ci[r, s])


def kinematics(F):
    """(Ci, J, I1, Jm23, dI1b) of deformation gradients F (..., 3, 3): C^-1, det F (signed),
    tr C, J^(-2/3) (NaN where J <= 0) and dI1b/dC = J^(-2/3) (I - I1/3 C^-1)."""
    F = np.asarray(F, dtype=float)
    shape = F.shape[:-2]
    Fr = np.ascontiguousarray(F).reshape(-1, 3, 3)
    n = len(Fr)
    Ci, dI1b = np.empty((n, 3, 3)), np.empty((n, 3, 3))
    J, I1, Jm23 = np.empty(n), np.empty(n), np.empty(n)
    _kinematics(Fr, Ci, J, I1, Jm23, dI1b)
    return (Ci.reshape(shape + (3, 3)), J.reshape(shape), I1.reshape(shape), Jm23.reshape(shape),
            dI1b.reshape(shape + (3, 3)))


@numba.njit(cache=True, nogil=True)
def _element_stiffness(G, dV, F, S, d, Ci, c_dd, c_IC, c_CC, c_sym, K):
    ne, nq = dV.shape
    nn = G.shape[2]
    vd, vI, vC = np.empty((nn, 3)), np.empty((nn, 3)), np.empty((nn, 3))
    GCi, GS = np.empty((nn, 3)), np.empty((nn, 3))
    dFt, CiFt, N = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    for e in range(ne):
        Ke = K[e]
        Ke[:, :] = 0.0
        for q in range(nq):
            g, f, ci, dd, s = G[e, q], F[e, q], Ci[e, q], d[e, q], S[e, q]
            cdd, cic, ccc, cs, dv = c_dd[e, q], c_IC[e, q], c_CC[e, q], c_sym[e, q], dV[e, q]
            for J in range(3):
                for i in range(3):
                    dFt[J, i] = dd[J, 0] * f[i, 0] + dd[J, 1] * f[i, 1] + dd[J, 2] * f[i, 2]
                    CiFt[J, i] = ci[J, 0] * f[i, 0] + ci[J, 1] * f[i, 1] + ci[J, 2] * f[i, 2]
            for i in range(3):
                for k in range(3):
                    N[i, k] = cs * (f[i, 0] * CiFt[0, k] + f[i, 1] * CiFt[1, k] + f[i, 2] * CiFt[2, k])
            for a in range(nn):
                for i in range(3):
                    vd[a, i] = g[a, 0] * dFt[0, i] + g[a, 1] * dFt[1, i] + g[a, 2] * dFt[2, i]
                    vI[a, i] = g[a, 0] * f[i, 0] + g[a, 1] * f[i, 1] + g[a, 2] * f[i, 2]
                    vC[a, i] = g[a, 0] * CiFt[0, i] + g[a, 1] * CiFt[1, i] + g[a, 2] * CiFt[2, i]
                    GCi[a, i] = g[a, 0] * ci[0, i] + g[a, 1] * ci[1, i] + g[a, 2] * ci[2, i]
                    GS[a, i] = g[a, 0] * s[0, i] + g[a, 1] * s[1, i] + g[a, 2] * s[2, i]
            for a in range(nn):
                for b in range(a, nn):
                    M = GCi[a, 0] * g[b, 0] + GCi[a, 1] * g[b, 1] + GCi[a, 2] * g[b, 2]
                    Kg = dv * (GS[a, 0] * g[b, 0] + GS[a, 1] * g[b, 1] + GS[a, 2] * g[b, 2])
                    for i in range(3):
                        for k in range(3):
                            v = (cdd * vd[a, i] * vd[b, k] + cic * (vC[a, i] * vI[b, k] + vI[a, i] * vC[b, k])
                                 + ccc * vC[a, i] * vC[b, k] + cs * vC[a, k] * vC[b, i] + M * N[i, k])
                            if i == k:
                                v += Kg
                            Ke[3 * a + i, 3 * b + k] += v
        for r in range(3 * nn):          # the lower blocks from the upper (K is symmetric)
            for c in range(3 * (r // 3)):
                Ke[r, c] = Ke[c, r]


def element_stiffness(G, dV, F, S, d, Ci, c_dd, c_IC, c_CC, c_sym):
    """(ne, 30, 30) element tangents, dof order 3 a + i:

        K[a i, b k] = sum_q  c_dd vd_ai vd_bk + c_IC (vC_ai vI_bk + vI_ai vC_bk) + c_CC vC_ai vC_bk
                            + c_sym vC_ak vC_bi + M_ab N_ik + dV (G S G^T)_ab delta_ik

    with vd = G d F^T, vI = G F^T, vC = G Ci F^T, M = G Ci G^T, N = c_sym F Ci F^T; G (ne, nq,
    10, 3) shape-function gradients, dV (ne, nq), F, S, d, Ci (ne, nq, 3, 3; S, d and Ci symmetric,
    as a PK2 stress and the tangent terms are: only the upper node blocks are summed), the coefficients
    broadcastable to (ne, nq) (`material.element_stiffness` folds dV and the relaxation factors
    into them)."""
    shape = np.shape(dV)
    c = lambda x: np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=float), shape))
    a = lambda x: np.ascontiguousarray(x, dtype=float)
    K = np.empty((shape[0], 3 * G.shape[2], 3 * G.shape[2]))
    _element_stiffness(a(G), c(dV), a(F), a(S), a(d), a(Ci), c(c_dd), c(c_IC), c(c_CC), c(c_sym), K)
    return K


@numba.njit(cache=True, nogil=True)
def _deformation_gradient(u, conn, G, F):
    ne, nq, nn, _ = G.shape
    for e in range(ne):
        for q in range(nq):
            f = F[e, q]
            for i in range(3):
                for J in range(3):
                    f[i, J] = 1.0 if i == J else 0.0
            for a in range(nn):
                ua = u[conn[e, a]]
                g = G[e, q, a]
                for i in range(3):
                    for J in range(3):
                        f[i, J] += ua[i] * g[J]


def deformation_gradient(u, conn, G):
    """F = I + Grad u (ne, nq, 3, 3) of the nodal displacements u (n_nodes, 3) on elements of
    nodes `conn` (ne, 10) with shape-function gradients G (ne, nq, 10, 3)."""
    F = np.empty(G.shape[:2] + (3, 3))
    _deformation_gradient(np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(conn), np.ascontiguousarray(G), F)
    return F


@numba.njit(cache=True, nogil=True)
def _internal_force(G, dV, F, S, fe):
    ne, nq, nn, _ = G.shape
    P = np.empty((3, 3))
    for e in range(ne):
        fe[e, :] = 0.0
        for q in range(nq):
            f, s, dv = F[e, q], S[e, q], dV[e, q]
            for i in range(3):
                for J in range(3):
                    P[i, J] = dv * (f[i, 0] * s[0, J] + f[i, 1] * s[1, J] + f[i, 2] * s[2, J])
            for a in range(nn):
                g = G[e, q, a]
                for i in range(3):
                    fe[e, 3 * a + i] += P[i, 0] * g[0] + P[i, 1] * g[1] + P[i, 2] * g[2]


_IDENTITY = np.eye(3)


def internal_force(G, dV, F, S=None):
    """Element internal forces (ne, 3 nn), f_ai = sum_q (F S)_iJ G_aJ dV, of second
    Piola-Kirchhoff stresses S (ne, nq, 3, 3) at deformation gradients F; with S None, F is
    the first Piola-Kirchhoff stress P itself."""
    if S is None:
        F, S = np.broadcast_to(_IDENTITY, np.shape(F)), F
    fe = np.empty((G.shape[0], 3 * G.shape[2]))
    _internal_force(np.ascontiguousarray(G), np.ascontiguousarray(dV, dtype=float), np.ascontiguousarray(F, dtype=float),
                    np.ascontiguousarray(S, dtype=float), fe)
    return fe


@numba.njit(cache=True, nogil=True)
def _darcy_terms(pe, Np, dNpdX, J, J_n, dV, kdt, Ci, s, p, Gp, fe_p):
    ne, nq, npn, _ = dNpdX.shape
    w = np.empty(3)
    for e in range(ne):
        fe_p[e, :] = 0.0
        for q in range(nq):
            pq = 0.0
            for b in range(npn):
                pq += pe[e, b] * Np[q, b]
            p[e, q] = pq
            for j in range(3):
                g = 0.0
                for b in range(npn):
                    g += pe[e, b] * dNpdX[e, q, b, j]
                Gp[e, q, j] = g
            ci = Ci[e, q]
            for j in range(3):      # kappa dt J dV C^-1 Grad p
                w[j] = kdt[e, q] * (ci[j, 0] * Gp[e, q, 0] + ci[j, 1] * Gp[e, q, 1] + ci[j, 2] * Gp[e, q, 2])
            dj = (J[e, q] - J_n[e, q]) * dV[e, q]
            for b in range(npn):
                fe_p[e, b] -= s * (dj * Np[q, b] + dNpdX[e, q, b, 0] * w[0] + dNpdX[e, q, b, 1] * w[1]
                                   + dNpdX[e, q, b, 2] * w[2])


def darcy_terms(pe, Np, dNpdX, J, J_n, dV, kdt, Ci, s):
    """The biphasic model's pore pressure p (ne, nq) and Grad p (ne, nq, 3) at the points from
    the element pressures pe (ne, npn) (shape functions Np (nq, npn), gradients dNpdX (ne, nq,
    npn, 3)), and its scaled mass residual (ne, npn):
    fe_p_b = -s sum_q [(J - J_n) dV N_b + kdt (C^-1 Grad p) . Grad N_b], kdt = kappa dt J dV."""
    ne, nq, npn, _ = dNpdX.shape
    p, Gp, fe_p = np.empty((ne, nq)), np.empty((ne, nq, 3)), np.empty((ne, npn))
    c = lambda x: np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=float), (ne, nq)))
    _darcy_terms(np.ascontiguousarray(pe, dtype=float), np.ascontiguousarray(Np, dtype=float), np.ascontiguousarray(dNpdX),
                 c(J), c(J_n), c(dV), c(kdt), np.ascontiguousarray(Ci), float(s), p, Gp, fe_p)
    return p, Gp, fe_p
