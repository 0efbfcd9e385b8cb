"""Interpolating a tet10 field at points of another mesh."""

import numpy as np
import pytest

from conftest import COARSE, FINE
from liverinv.fem.probe import Probe
from liverinv.mesh import read_mesh


@pytest.mark.skipif(not FINE.exists(), reason="benchmark meshes not available")
def test_quadratic_field_of_the_fine_mesh_is_exact_at_coarse_nodes():
    fine, coarse = read_mesh(FINE), read_mesh(COARSE)
    def field(X):   # quadratic in X: reproduced exactly by tet10 on straight elements
        x, y, z = X.T
        return np.stack([x * y + 3 * z, z ** 2 - x, 2 * x + y * z], axis=-1)
    probe = Probe(fine.points, fine.cells, coarse.points)
    got = probe(np.stack([field(fine.points), 2 * field(fine.points)]))   # (time, node, comp)
    ref = field(coarse.points)
    assert got.shape == (2, coarse.n_nodes, 3)
    # the isoparametric map is inverted exactly: node coordinates come back to round-off
    np.testing.assert_allclose(probe(fine.points), coarse.points, atol=1e-14)
    assert probe.outside.max() < 1e-2          # curved faces: points sit in their element
    # a quadratic field of X is quadratic in the element coordinates only on straight
    # elements; the fine mesh's curved side elements leave 1e-5 of the field's range
    scale = np.abs(ref).max()
    np.testing.assert_allclose(got[0], ref, atol=2e-5 * scale)
    np.testing.assert_allclose(got[1], 2 * ref, atol=4e-5 * scale)
    P, C = fine.points, fine.cells
    edges = ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3))
    bow = np.max([np.abs(P[C[:, 4 + j]] - (P[C[:, a]] + P[C[:, b]]) / 2).max(axis=1) for j, (a, b) in enumerate(edges)], axis=0)
    straight = bow[probe.element] < 1e-12
    assert straight.mean() > 0.7
    np.testing.assert_allclose(got[0][straight], ref[straight], atol=1e-12 * scale)
