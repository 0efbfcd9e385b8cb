r"""What the tracker would report for a given displacement field: the linearized nodal
Lucas-Kanade estimate as a sparse linear operator (an observation operator).

At its fixed point the tracker's stage 1 (`tracking.NodalTracker`) solves, for node n and a
frame pair with the tissue moved by u(x) (brightness constancy, u small over a pair),

    sum_i W_ni g_i g_i^T v_n = sum_i W_ni g_i g_i^T u(x_i)

(to first order in u: the iteration's residual is J1 - J0 - g . V = -g . u), i.e.

    v_n = A_n^-1 sum_i W_ni g_i g_i^T u(x_i),      A_n = sum_i W_ni g_i g_i^T,

a structure-tensor-weighted average of the motion over the node's window (W the tracker's
windows, g the image gradient). Where the motion varies over a window (the peaked field
under the punch) this average is not the motion at the node: on the Table 1 benchmark the
tracked motion is ~6 % smaller than the true nodal motion in the confidence-weighted
aggregate, which biases kappa by about -2 %. Comparing the model *through the same
operator* (the model's field evaluated at the voxel centres with its own shape functions,
then window-averaged with frame 0's gradients) removes that bias to first order; what is
left is the change of the gradients with deformation over the test (second order) and
image noise.

The operator maps the model's nodal displacement (n_model, 3) to the tracked nodes
(N, 3), in metres along mesh axes; it is linear, so it applies equally to displacements and
to velocities. Built once per fit (`TrackingObservation.build`): one sparse matrix
(3 N x 3 n_model).
"""

from __future__ import annotations

import ast
import logging

import numpy as np
import scipy.sparse as sp

from .tracking import NodalTracker, TrackOptions, _PAIRS
from .weights import VoxelWeights

log = logging.getLogger(__name__)

__all__ = ["TrackingObservation", "track_options_of", "tracking_observation"]


def track_options_of(flow) -> tuple[TrackOptions, tuple, str]:
    """(TrackOptions, stride, window) a flow Dataset was tracked with (its attributes)."""
    try:
        opts = TrackOptions(**ast.literal_eval(flow.attrs["options"]))
        stride = tuple(ast.literal_eval(flow.attrs["stride"]))
        window = str(flow.attrs["window"])
    except (KeyError, ValueError, SyntaxError, TypeError) as e:
        raise ValueError(f"the flow does not record its tracking options ({e}); track it again "
                         "with `liverinv track`") from None
    return opts, stride, window


class TrackingObservation:
    """u_model (..., n_model, 3) -> the tracker's estimate at the tracked nodes (..., N, 3).

    Attributes: `matrix` (3 N, 3 n_model) sparse, node-major (x, y, z interleaved).
    """

    DENSE_FROM = 0.02          # fraction of non-zeros from which the operator is applied dense
    DENSE_MAX_BYTES = 3e8

    def __init__(self, matrix: sp.csr_matrix):
        self.matrix = matrix.tocsr()
        self.N, self.n_model = matrix.shape[0] // 3, matrix.shape[1] // 3
        # the tracker's windows overlap many model elements: on the coarse benchmark mesh the
        # operator is 14 % full (2.9e6 of 4470^2), and a dense product (BLAS) applies it to the
        # diagnosis's 46 x 31 fields in 0.36 s against 1.3 s sparse
        size = matrix.shape[0] * matrix.shape[1]
        self._dense = (self.matrix.toarray() if self.matrix.nnz >= self.DENSE_FROM * size
                       and 8 * size <= self.DENSE_MAX_BYTES else None)
        self._rows = None      # (key, model dofs seen, operator) of the last `at_nodes` node set

    @classmethod
    def build(cls, volume0, grid, track_points, track_cells, model_points, model_cells,
              options: TrackOptions | None = None, stride=(2, 2, 1), window="subtet"):
        """The operator of a tracker (`options`, `stride`, `window` as `track_bundle` used
        them) on the tracking mesh, for a model on (model_points, model_cells), with the
        gradients of the first volume `volume0`."""
        from ..fem.probe import Probe

        opts = options or TrackOptions()
        vw = VoxelWeights.build(track_points, track_cells, grid, stride=stride, window=window)
        tracker = NodalTracker(vw, track_points, opts)
        W = tracker.W                                             # (N, m) solve windows
        vol = np.asarray(volume0, np.float32)
        if opts.presmooth_vox > 0:
            from scipy import ndimage
            vol = ndimage.gaussian_filter(vol, opts.presmooth_vox)
        ijk = np.stack(np.unravel_index(vw.voxels, grid.shape), 1)
        g = np.stack([gr[tuple(ijk.T)] for gr in np.gradient(vol)], 1).astype(float)
        shape = np.asarray(grid.shape)
        g *= np.all((ijk >= 1) & (ijk <= shape - 2), axis=1)[:, None]   # the tracker's valid voxels
        # the model's field at the voxel centres (its quadratic shape functions)
        P = Probe(model_points, model_cells, grid.centres(vw.voxels)).matrix.tocsc()   # (m, n_model)
        S = {}
        for a, b in _PAIRS:
            S[a, b] = S[b, a] = (W @ sp.diags(g[:, a] * g[:, b]) @ P).tocsr()        # (N, n_model)
        A = np.stack([[np.asarray(S[a, b].sum(1)).ravel() for b in range(3)] for a in range(3)], -1)
        A = np.moveaxis(A, 0, 1)                                  # (N, 3, 3), rows of P sum to 1
        tr = np.trace(A, axis1=1, axis2=2)
        A = A + 1e-9 * max(tr.max(), 1e-300) * np.eye(3)
        Ainv = np.linalg.inv(A)
        # voxel units: v_vox = Ainv sum_c S[., c] u_vox_c, u_vox = T u_m, v_m = T^-1 v_vox
        h, R = np.asarray(grid.spacing_m), grid.R
        T = (R / h).T                                             # (3, 3): u_vox = T u_m
        Tinv = R * h                                              # v_m = Tinv v_vox
        L = {(a, c): sum(sp.diags(Ainv[:, a, b]) @ S[b, c] for b in range(3)) for a in range(3) for c in range(3)}
        def block(al, be):   # (Tinv L T)[al, be]; only the non-zero terms (keeps L's pattern)
            terms = [Tinv[al, a] * T[c, be] * L[a, c] for a in range(3) for c in range(3)
                     if Tinv[al, a] * T[c, be] != 0]
            return sum(terms[1:], terms[0]) if terms else None

        O = sp.bmat([[block(al, be) for be in range(3)] for al in range(3)], format="csr")   # component-major
        N, n = W.shape[0], P.shape[1]
        rows = np.arange(3 * N).reshape(3, N).T.ravel()           # node-major order
        cols = np.arange(3 * n).reshape(3, n).T.ravel()
        O = O[rows][:, cols]
        log.info("tracking observation: %d tracked nodes x %d model nodes, %d nonzeros", N, n, O.nnz)
        return cls(O)

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """Model nodal field (..., n_model, 3) as the tracker would see it (..., N, 3)."""
        u = np.asarray(u, float)
        lead = u.shape[:-2]
        flat = u.reshape(-1, 3 * self.n_model)                    # (k, 3 n_model)
        out = flat @ self._dense.T if self._dense is not None else (self.matrix @ flat.T).T
        return out.reshape(lead + (self.N, 3))

    def at_nodes(self, u: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """`self(u)[..., nodes, :]` from the operator's rows of `nodes` and the model dofs they
        see only (the sub-operator is kept for the next call with the same nodes). The
        sensitivities of a fit need the tracked nodes with confidence only: on the coarse
        benchmark data 60 % of the nodes seeing 75 % of the model dofs, 0.45 of the product."""
        u = np.asarray(u, float)
        nodes = np.asarray(nodes, np.intp)
        key = nodes.tobytes()
        if self._rows is None or self._rows[0] != key:
            M = self.matrix[(3 * nodes[:, None] + np.arange(3)).ravel()]
            seen = np.unique(M.indices)
            M = M[:, seen]
            size = M.shape[0] * M.shape[1]
            self._rows = (key, seen, M.toarray() if self._dense is not None and 8 * size <= self.DENSE_MAX_BYTES
                          else M.tocsr())
        _, seen, M = self._rows
        flat = u.reshape(-1, 3 * self.n_model)[:, seen]
        out = flat @ M.T if isinstance(M, np.ndarray) else (M @ flat.T).T
        return out.reshape(u.shape[:-2] + (len(nodes), 3))


def tracking_observation(bundle, flow, tracking_mesh, model_mesh):
    """The tracker's observation operator for a flow of `bundle` tracked on `tracking_mesh`
    (a path or a TetMesh), for a model on the TetMesh `model_mesh`."""
    from ..mesh import read_mesh

    opts, stride, window = track_options_of(flow)
    tm = tracking_mesh if hasattr(tracking_mesh, "points") else read_mesh(tracking_mesh, required=())
    if tm.n_nodes != flow.sizes.get("node") or not np.allclose(tm.points, flow.X.values, rtol=0, atol=1e-9):
        raise ValueError(f"{tm.path} is not the mesh the flow was tracked on (its nodes differ)")
    return TrackingObservation.build(bundle.frame(0), bundle.grid, tm.points, tm.cells, model_mesh.points,
                                     model_mesh.cells, opts, stride, window)
