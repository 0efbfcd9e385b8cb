"""The compiled kernels of `liverinv.fem.kernels` against numpy's textbook forms on the coarse
benchmark mesh (random motions and stresses, an inverted point included)."""

import numpy as np

from liverinv.fem import kernels
from liverinv.fem.space import Space


def test_kinematics_equal_numpy(rng):
    F = np.eye(3) + 0.2 * rng.standard_normal((50, 4, 3, 3))
    F[0, 0] = np.diag([1.0, 1.0, -0.5])          # inverted: J < 0
    Ci, J, I1, Jm23, dI1b = kernels.kinematics(F)
    C = np.swapaxes(F, -1, -2) @ F
    assert np.allclose(Ci, np.linalg.inv(C), rtol=1e-12, atol=1e-12)
    assert np.allclose(J, np.linalg.det(F), rtol=1e-13, atol=0)
    assert np.allclose(I1, np.trace(C, axis1=-2, axis2=-1), rtol=1e-14)
    ok = J > 0
    assert np.isnan(Jm23[0, 0]) and np.isnan(dI1b[0, 0]).all() and ok.sum() == J.size - 1
    assert np.allclose(Jm23[ok], J[ok] ** (-2 / 3), rtol=1e-14)
    ref = Jm23[..., None, None] * (np.eye(3) - I1[..., None, None] / 3 * np.linalg.inv(C))
    assert np.allclose(dI1b[ok], ref[ok], rtol=1e-11, atol=1e-12)


def test_deformation_gradient_and_internal_force_equal_numpy(coarse_mesh, rng):
    sp = Space(coarse_mesh)
    u = 1e-3 * rng.standard_normal((coarse_mesh.n_nodes, 3))
    F = sp.deformation_gradient(u)
    ref = np.eye(3) + np.einsum("eai,eqaJ->eqiJ", u[sp.conn], sp.dNdX)
    assert np.abs(F - ref).max() < 1e-14
    S = rng.standard_normal(F.shape)
    f = sp.internal_force(F, S)
    f_ref = np.einsum("eqiJ,eqaJ,eq->eai", F @ S, sp.dNdX, sp.dV).reshape(len(F), 30)
    assert np.abs(f - f_ref).max() < 1e-13 * np.abs(f_ref).max()
    assert np.abs(sp.internal_force(F @ S) - f_ref).max() < 1e-13 * np.abs(f_ref).max()
    some = np.array([3, 17, 400])
    assert np.abs(sp.internal_force(F[some], S[some], some) - f_ref[some]).max() < 1e-13 * np.abs(f_ref).max()
    assert np.array_equal(sp.deformation_gradient(u, some), F[some])


def test_darcy_terms_equal_numpy(rng):
    ne, nq = 30, 8
    pe, Np = rng.standard_normal((ne, 4)), rng.random((nq, 4))
    dNpdX = rng.standard_normal((ne, nq, 4, 3))
    J, J_n, dV, kdt = 1 + 0.1 * rng.random((4, ne, nq))
    A = rng.standard_normal((ne, nq, 3, 3))
    Ci = A @ np.swapaxes(A, -1, -2) + np.eye(3)
    p, Gp, fe_p = kernels.darcy_terms(pe, Np, dNpdX, J, J_n, dV, kdt, Ci, 2.5)
    assert np.allclose(p, pe @ Np.T, rtol=1e-14, atol=1e-14)
    assert np.allclose(Gp, np.einsum("eb,eqbj->eqj", pe, dNpdX), rtol=1e-13, atol=1e-13)
    ref = -2.5 * (((J - J_n) * dV) @ Np + np.einsum("eqbj,eq,eqjk,eqk->eb", dNpdX, kdt, Ci, Gp))
    assert np.allclose(fe_p, ref, rtol=1e-12, atol=1e-12)
