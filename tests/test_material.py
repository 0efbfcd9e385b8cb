"""Constitutive kernels against finite differences and closed-form relaxation."""

import numpy as np
import pytest

from liverinv.fem.material import (QLVState, first_elasticity, hyperelastic_split,
                                   relaxation_factors)
from liverinv.laws import LAWS

PARAM_SETS = {
    "elastic": dict(C1=200.0, C2=5000.0, D1=1.5e-3, D2inv=0.0),
    "neo-Hookean": dict(C1=200.0, C2=0.0, D1=1.5e-3, D2inv=0.0),
    "quartic bulk": dict(C1=83.9, C2=40.9, D1=4.71e-4, D2inv=1 / 2.22e-5),
}


def energy(F, C1, C2, D1, D2inv):
    C = F.T @ F
    J = np.linalg.det(F)
    I1b = J ** (-2 / 3) * np.trace(C)
    return C1 * (I1b - 3) + C2 * (I1b - 3) ** 2 + (J - 1) ** 2 / D1 + D2inv * (J - 1) ** 4


def random_F(rng, size=0.25):
    return np.eye(3) + size * rng.standard_normal((3, 3))


@pytest.mark.parametrize("name", PARAM_SETS)
def test_stress_is_energy_derivative(name, rng):
    p = PARAM_SETS[name]
    for _ in range(5):
        F = random_F(rng)
        S_iso, S_vol, *_ = hyperelastic_split(F[None], **p)
        P = F @ (S_iso[0] + S_vol[0])
        h = 1e-6
        P_fd = np.zeros((3, 3))
        for i in range(3):
            for j in range(3):
                E = np.zeros((3, 3)); E[i, j] = h
                P_fd[i, j] = (energy(F + E, **p) - energy(F - E, **p)) / (2 * h)
        assert np.allclose(P, P_fd, rtol=1e-6, atol=1e-6 * np.abs(P).max())


def _fd_tangent(fun, F, h=1e-6):
    A = np.zeros((3, 3, 3, 3))
    for k in range(3):
        for L in range(3):
            E = np.zeros((3, 3)); E[k, L] = h
            A[:, :, k, L] = (fun(F + E) - fun(F - E)) / (2 * h)
    return A


@pytest.mark.parametrize("name", PARAM_SETS)
def test_tangent_is_stress_derivative(name, rng):
    p = PARAM_SETS[name]
    for _ in range(5):
        F = random_F(rng)
        S_iso, S_vol, CC_iso, CC_vol, _ = hyperelastic_split(F[None], **p)
        P, A = first_elasticity(F[None], S_iso + S_vol, CC_iso + CC_vol)

        def pk1(G):
            a, b, *_ = hyperelastic_split(G[None], **p, tangent=False)
            return G @ (a[0] + b[0])

        A_fd = _fd_tangent(pk1, F)
        assert np.abs(A[0] - A_fd).max() < 1e-6 * np.abs(A_fd).max()
        # major symmetry: the global tangent is symmetric
        assert np.allclose(A[0], A[0].transpose(2, 3, 0, 1), atol=1e-9 * np.abs(A).max())


@pytest.mark.parametrize("law", sorted(LAWS))
def test_algorithmic_tangent_of_every_law(law, rng, coarse_mesh):
    """Global reduced tangent of every named law (with QLV history) against central
    differences of the reduced residual at a deformed state."""
    from liverinv.fem.indentation import Indentation
    from liverinv.fem.space import Space
    from liverinv.laws import get_law

    space = Space(coarse_mesh)
    model = Indentation(space, get_law(law).resolve())
    state = model.new_state()
    q = np.zeros(model.n_red)
    # a smooth indentation-like state, then one QLV step of history
    X = coarse_mesh.points
    u = np.zeros_like(X)
    u[:, 2] = -1e-3 * np.exp(-(X[:, 0] ** 2 + X[:, 1] ** 2) / 1e-4) * X[:, 2] / 0.0303
    u[:, 0] = 2e-4 * X[:, 1] * X[:, 2] / 0.0303 ** 2
    q = np.zeros(model.n_red)
    mask = model.asm.index >= 0
    q[model.asm.index[mask]] = (u.ravel() * model.asm.sign)[mask]
    ev0 = model.evaluate(0.5 * q, 0.05, state)
    state = model.commit(state, ev0, 0.05)
    ev = model.evaluate(q, 0.05, state)
    v = rng.standard_normal(model.n_red) * 1e-4
    h = 2e-4
    r_p = model.evaluate(q + h * v, 0.05, state, tangent=False).r
    r_m = model.evaluate(q - h * v, 0.05, state, tangent=False).r
    fd = (r_p - r_m) / (2 * h)
    Kv = ev.K @ v
    assert np.linalg.norm(Kv - fd) < 1e-6 * np.linalg.norm(fd)
    assert abs(ev.K - ev.K.T).max() < 1e-10 * abs(ev.K).max()


def _uniaxial(lam):
    """Isochoric stretch along z plus a volume change, a homogeneous state."""
    return np.diag([lam ** -0.45, lam ** -0.45, lam])


def test_relaxation_after_a_step_matches_prony_series():
    """Step of deformation, then hold: S(t) = (1 - g1 + g1 e^{-t/tau}) S0_iso + (same) S0_vol."""
    p = dict(C1=200.0, C2=5000.0, D1=1.5e-3, D2inv=0.0)
    g1, tg, k1, tk = 0.4, 0.06, 0.3, 0.2
    F = _uniaxial(0.85)[None]
    S_iso, S_vol, *_ = hyperelastic_split(F, **p, tangent=False)
    st = QLVState((1,))
    # the step: a ramp over a very short time is the step response
    dt0 = 1e-9
    def stress(st, dt, S_iso, S_vol):
        a_g, e_g, c_g = relaxation_factors(dt, g1, tg)
        a_k, e_k, c_k = relaxation_factors(dt, k1, tk)
        S = (a_g * S_iso + g1 * (e_g * st.H_iso - c_g * st.S0_iso)
             + a_k * S_vol + k1 * (e_k * st.H_vol - c_k * st.S0_vol))
        new = QLVState((1,))
        new.H_iso = e_g * st.H_iso + c_g * (S_iso - st.S0_iso)
        new.H_vol = e_k * st.H_vol + c_k * (S_vol - st.S0_vol)
        new.S0_iso, new.S0_vol = S_iso, S_vol
        return S, new
    S, st = stress(st, dt0, S_iso, S_vol)
    t = 0.0
    for dt in [0.01, 0.05, 0.1, 0.5]:
        t += dt
        S, st = stress(st, dt, S_iso, S_vol)
        exact = (1 - g1 + g1 * np.exp(-t / tg)) * S_iso + (1 - k1 + k1 * np.exp(-t / tk)) * S_vol
        assert np.allclose(S, exact, rtol=1e-7, atol=1e-9 * np.abs(exact).max())


def test_constant_rate_ramp_matches_convolution():
    """Through the FE kernel: a homogeneous ramp of F over time integrated with the model's
    recursive update, against a fine quadrature of the convolution integral."""
    from scipy.integrate import quad

    p = dict(C1=200.0, C2=5000.0, D1=1.5e-3, D2inv=0.0)
    g1, tg = 0.4, 0.06
    T = 0.3
    F_of = lambda t: _uniaxial(1 - 0.5 * t)[None]  # 15% compression at T
    S0 = lambda t: hyperelastic_split(F_of(t), **p, tangent=False)[0][0]
    G = lambda s: 1 - g1 + g1 * np.exp(-s / tg)
    # reference: S(T) = int_0^T G(T - s) dS0/ds ds, component zz and xx
    h = 1e-6
    ref = np.zeros((3, 3))
    for (i, j) in [(0, 0), (2, 2)]:
        dS = lambda s: (S0(s + h)[i, j] - S0(s - h)[i, j]) / (2 * h)
        ref[i, j] = quad(lambda s: G(T - s) * dS(s), 0, T, epsabs=1e-10, limit=200)[0]
    errs = []
    for n in (10, 20):
        dt = T / n
        st = QLVState((1,))
        for k in range(1, n + 1):
            S_iso = hyperelastic_split(F_of(k * dt), **p, tangent=False)[0]
            a, e, c = relaxation_factors(dt, g1, tg)
            S = a * S_iso + g1 * (e * st.H_iso - c * st.S0_iso)
            st.H_iso = e * st.H_iso + c * (S_iso - st.S0_iso)
            st.S0_iso = S_iso
        errs.append(abs(S[0, 2, 2] - ref[2, 2]) / abs(ref[2, 2]))
    assert errs[1] < 2e-3
    assert errs[1] < errs[0] / 3  # second-order convergence in dt


def test_structured_element_stiffness_equals_tensor_form(coarse_mesh, rng):
    """The element stiffness assembled from tensor-product terms equals the textbook
    G_aJ A_iJkL G_bL with the full first elasticity tensor."""
    from liverinv.fem.material import element_stiffness, full_tangents, hyperelastic_terms
    from liverinv.fem.space import Space

    sp = Space(coarse_mesh)
    G, dV = sp.dNdX[:40], sp.dV[:40]
    F = np.eye(3) + 0.15 * rng.standard_normal((40, sp.nq, 3, 3))
    S_iso, S_vol, t, J = hyperelastic_terms(F, 200.0, 5000.0, 1.5e-3, 1 / 2.2e-2)
    a_g, a_k = 0.8 * np.ones(J.shape), 0.6 * np.ones(J.shape)
    S = 0.7 * S_iso + 0.5 * S_vol
    K = element_stiffness(G, dV, F, S, t, a_g, a_k)
    CC_iso, CC_vol = full_tangents(t)
    P, A = first_elasticity(F, S, a_g[..., None, None, None, None] * CC_iso
                            + a_k[..., None, None, None, None] * CC_vol)
    K_ref = np.einsum("eqaJ,eqiJkL,eqbL,eq->eaibk", G, A, G, dV).reshape(40, 30, 30)
    assert np.abs(K - K_ref).max() < 1e-10 * np.abs(K_ref).max()
