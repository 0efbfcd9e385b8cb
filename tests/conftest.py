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
