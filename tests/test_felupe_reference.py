"""Quick checks of the felupe peer reference (benchmarks/felupe_reference.py)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("felupe")

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "felupe_reference.py"
COARSE = Path("/work/shared/benchmark/cylinder_coarse.msh")
ELASTIC = {"C1": 200.0, "C2": 5000.0, "D1": 1.5e-3}


@pytest.fixture(scope="module")
def fr():
    spec = importlib.util.spec_from_file_location("felupe_reference", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _energy(F, C1, C2, D1):
    J = np.linalg.det(np.moveaxis(F, (0, 1), (-2, -1)))
    I1b = J ** (-2 / 3) * np.einsum("iJ...,iJ...->...", F, F)
    return C1 * (I1b - 3) + C2 * (I1b - 3) ** 2 + (J - 1) ** 2 / D1


def test_stress_and_tangent_are_derivatives(fr):
    rng = np.random.default_rng(1)
    F = np.eye(3)[:, :, None, None] + 0.3 * rng.standard_normal((3, 3, 2, 3))
    P = fr._stress([F, None], **ELASTIC)[0]
    A = fr._elasticity([F], **ELASTIC)[0]
    h = 1e-6
    P_fd, A_fd = np.zeros_like(P), np.zeros_like(A)
    for k in range(3):
        for L in range(3):
            dF = np.zeros_like(F)
            dF[k, L] = h
            P_fd[k, L] = (_energy(F + dF, **ELASTIC) - _energy(F - dF, **ELASTIC)) / (2 * h)
            A_fd[:, :, k, L] = (fr._stress([F + dF, None], **ELASTIC)[0]
                                - fr._stress([F - dF, None], **ELASTIC)[0]) / (2 * h)
    assert np.abs(P - P_fd).max() < 1e-6 * np.abs(P).max()
    assert np.abs(A - A_fd).max() < 1e-6 * np.abs(A).max()


def test_small_strain_moduli(fr):
    """At F = I the tangent is linear elasticity with mu = 2 C1, K = 2 / D1."""
    A = fr._elasticity([np.eye(3)[:, :, None, None]], **ELASTIC)[0][..., 0, 0]
    mu, K = 2 * ELASTIC["C1"], 2 / ELASTIC["D1"]
    eye = np.eye(3)
    expected = (mu * (np.einsum("ik,jl->ijkl", eye, eye) + np.einsum("il,jk->ijkl", eye, eye))
                + (K - 2 * mu / 3) * np.einsum("ij,kl->ijkl", eye, eye))
    assert np.allclose(A, expected, rtol=1e-12, atol=1e-9 * K)


@pytest.mark.skipif(not COARSE.exists(), reason="benchmark mesh not available")
def test_first_two_benchmark_steps(fr):
    """The first 2 of the 46 loading steps of the benchmark run (d = 0.2, 0.4 mm)."""
    out = fr.run_felupe(COARSE, **ELASTIC, depth=4e-4, steps=2, unload=False)
    assert out["completed"] and out["n_cells"] == 819 and out["n_nodes"] == 1490
    assert np.allclose(out["depth"], [0.0, 2e-4, 4e-4])
    # values of the full 46 + 46 step run that gives 0.198546 / 0.846028 N
    assert out["force"][1:] == pytest.approx([0.00403111, 0.00828418], rel=2e-6)
    assert out["newton_iterations"] == 8
    assert np.isnan(out["force_4p6mm"])


def test_arguments_are_checked(fr):
    with pytest.raises(ValueError, match="quadrature"):
        fr._load_mesh(COARSE, "tet10-99pt")
    with pytest.raises(ValueError, match="steps"):
        fr.run_felupe(COARSE, **ELASTIC, steps=0)
    with pytest.raises(ValueError, match="solver"):
        fr.run_felupe(COARSE, **ELASTIC, solver="umfpack")
