import os
from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
BENCH = SHARED / "benchmark"
COARSE = BENCH / "cylinder_coarse.msh"
FINE = BENCH / "cylinder_fine.msh"

BENCH_ELASTIC = dict(C1=200.0, C2=5000.0, D1=1.5e-3)


def pytest_configure(config):
    os.environ.setdefault("OMP_NUM_THREADS", "2")


@pytest.fixture(scope="session")
def coarse_mesh():
    from liverinv.mesh import read_mesh
    if not COARSE.exists():
        pytest.skip(f"benchmark mesh {COARSE} not found")
    return read_mesh(COARSE)


@pytest.fixture(scope="session")
def coarse_forward(coarse_mesh):
    from liverinv.forward import ForwardModel
    return ForwardModel(coarse_mesh)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


#: the paper's indenter noise (3.9 um, 13 mN RMS) and a planted tracking error at confidence 1
SIGMA_D, SIGMA_F, SIGMA_TRACK = 3.9e-6, 13e-3, 2e-6


def noisy_measurements(run, seed):
    """Measurements of a run: the indenter record at 100 Hz with the paper's noise, and the
    exact nodal motion of every other frame pair with tracking noise SIGMA_TRACK / sqrt(c),
    the confidences c uniform in [0.2, 1]."""
    from liverinv.identify.objective import Measurements
    rng = np.random.default_rng(seed)
    t = run.time.values
    t_ind = np.arange(0, t[-1] + 1e-9, 0.01)
    depth = np.interp(t_ind, t, run.indenter_depth.values) + SIGMA_D * rng.standard_normal(t_ind.size)
    force = np.interp(t_ind, t, run.indenter_force.values) + SIGMA_F * rng.standard_normal(t_ind.size)
    idx = np.arange(0, len(t), 2)
    u = run.u.values
    c = rng.uniform(0.2, 1.0, (len(idx) - 1,) + u.shape[1:])
    u_of = u[idx[1:]] - u[idx[:-1]] + SIGMA_TRACK / np.sqrt(c) * rng.standard_normal(c.shape)
    return Measurements(t_ind, depth, force, t[idx[:-1]], t[idx[1:]], u_of, c)

