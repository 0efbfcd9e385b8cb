"""Nodal Lucas-Kanade motion tracking with confidence (the paper's Appendix, Eqs. A.1-A.4).

For every mesh node n and every pair of frames (k, k+1) the tracker finds the displacement
v_n (voxels) that best satisfies the optical-flow equation (A.1) over the voxels i of the
elements around the node, each row weighted by the node's shape function N_n,i (A.2-A.3):

    sum_i N_n,i g_i g_i^T v_n = - sum_i N_n,i g_i dI_i,

with g the spatial gradient of frame k at the tissue's position (central differences;
`symmetric_gradient` averages it with frame k+1's at the warm-start position, which did
not help on the benchmark) and dI the frame difference.
All nodes are solved at once: the six gradient products are one sparse product with the
(node x voxel) weight matrix W of `weights.VoxelWeights` (built once per mesh and grid),
the 3 x 3 systems are inverted together.

Minimum spatial support (`min_support_vox`, default 20 voxels). The shape-function windows
of small elements hold too few independent speckles: on moved-scatterer data their
estimates are noise-limited (at the mid-confidence nodes of the benchmark the window sum
is ~1.8x smaller than optical_flow_ilk's 15-voxel cube, and the error ~1.4x larger). Each
node's window is therefore ``max(N_n, 1 - r / R)``, r the distance in voxels from the node
(reference configuration, over the voxels inside the mesh), see
`VoxelWeights.with_min_support`; nodes whose elements reach further than R keep their
shape function. The confidence (A.4) and the coverage test still use the node's own
elements (`confidence_window="elements"`), so the set of confident nodes is the paper's.
Benchmark (100 frames, coarse mesh, c > 0.1 / c > 0.05, voxel RMS), R = 0 -> 16 -> 20 -> 26:
moved scatterers 0.0089 / 0.0179 -> 0.0059 / 0.0091 -> 0.0051 / 0.0078 -> 0.0053 / 0.0080;
warped 0.0045 / 0.0054 -> 0.0033 / 0.0042 -> 0.0037 / 0.0050 -> 0.0050 / 0.0070 (larger
windows average over the strain gradient near the punch); moved + noise + decorrelation
0.067 / 0.087 -> 0.052 / 0.055 -> 0.043 / 0.044; warped + noise 0.019 / 0.025 -> 0.015 /
0.016 -> 0.012 / 0.013. About 1.5x the CPU time of R = 0.

Following the material point. Tracking is Lagrangian: a node's neighbourhood is the set of
*reference* voxels inside its elements, and at frame k they are looked up where the tissue
has moved to, ``x = X + U_k(X)``, U_k the motion accumulated over the previous pairs,
interpolated from the nodes with the mesh's shape functions. So the neighbourhood used
between frames k and k+1 is the node's deformed neighbourhood at frame k: it moves and
deforms with the tissue, and W never changes. Frame k's values there are those sampled at
the end of the previous pair (no re-interpolation).

Iterative refinement (warp and re-solve). Frame k+1 is sampled with cubic B-splines at
``X + U_k + V(X)``, V the current nodal estimate interpolated to the voxels, each node's
rows are moved to its own translation by a first-order correction
``I(p + v_n) ~ I(p + V) + g . (v_n - V)``, and the system is solved again for the
correction, up to `max_iterations` times or until the largest correction is below `tol_vox`.
The first estimate is the previous pair's motion (warm start); with one iteration and no
warm start this is exactly the paper's single-pass estimate. The refinement contracts the
error by only about 0.5-0.65 per iteration on speckle (log-compressed B-mode: the central
difference gradient overstates the slope over a fraction of a voxel), so an unconverged
estimate keeps part of the warm start: a lag behind the motion where it changes speed. With
the former default of 2 iterations the tracked motion of the Table 1 data lagged by 0.19 of
the change between consecutive pairs (e ~ -0.19 (d_k - d_k-1) against the observed truth),
which biased the identified permeability by about -2 %; 8 iterations (the default) leave
0.012. On a reversing compression (tests) 2 iterations err 0.067 voxel at the reversal, 8
iterations 0.015 (the window-averaging floor of that field). About 1.7x the tracking time.

Stage 2, interpolated model (`interpolated_iterations`, default 0): the translation
estimate is a texture-weighted window average of the motion, biased where the motion
varies over the window (strain gradients, one-sided windows at surfaces, uneven texture).
Then each confident node's window is compared at the interpolated motion V(p) itself and
the correction solved with the node's own system (block Jacobi on the joint least-squares
problem of all nodes); its fixed point has no window-average bias for motion the mesh can
represent. Nodes below `interpolated_min_confidence` keep their stage-1 values so that
poorly determined nodes cannot disturb their neighbours. It halves the error on noise-free
warped data (the paper's validation) but amplifies noise and speckle decorrelation
(moved scatterers, noisy data), hence off by default; see benchmarks/bench_tracking.py.

Confidence (A.4): ``c_n,j = sum_i N_n,i |dI_i/dj|`` over the voxels in view, normalized by the
largest nodal value of the frame pair so c lies in [0, 1]. Nodes whose current position is
outside the volume, or with less than `min_coverage` of their weight inside it, get c = 0.
With ``confidence="mean"`` the sum is divided by the weight in view (a texture measure that
does not grow with the neighbourhood).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..parallel import RowBlocks, map_coordinates
from .weights import VoxelWeights

log = logging.getLogger(__name__)

__all__ = ["TrackOptions", "NodalTracker"]

_PAIRS = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]


@dataclass
class TrackOptions:
    """Options of the nodal Lucas-Kanade tracker (voxel units where named so)."""

    max_iterations: int = 8
    tol_vox: float = 1e-5
    warm_start: bool = True
    min_coverage: float = 0.5
    confidence: str = "sum"
    regularization: float = 1e-4
    presmooth_vox: float = 0.0
    interpolated_iterations: int = 0
    symmetric_gradient: bool = False
    interpolated_min_confidence: float = 0.05
    min_support_vox: float = 20.0
    confidence_window: str = "elements"

    def __post_init__(self):
        if self.confidence not in ("sum", "mean"):
            raise ValueError(f"confidence must be 'sum' or 'mean', not {self.confidence!r}")
        if self.confidence_window not in ("elements", "solve"):
            raise ValueError(f"confidence_window must be 'elements' or 'solve', not {self.confidence_window!r}")
        if self.max_iterations < 1:
            raise ValueError("max_iterations must be >= 1")


class NodalTracker:
    """Frame-to-frame nodal motion of a mesh in an image sequence.

    Parameters
    ----------
    weights : VoxelWeights
        Hat weights of the tracking mesh on the image grid (built once).
    points_m : (n, 3) reference node coordinates of the tracking mesh, m
    options : TrackOptions

    Examples
    --------
    >>> tr = NodalTracker(weights, points)                    # doctest: +SKIP
    >>> tr.start(volume0)                               # doctest: +SKIP
    >>> v_vox, c = tr.step(volume1)                     # doctest: +SKIP
    """

    def __init__(self, weights: VoxelWeights, points_m, options: TrackOptions | None = None):
        self.vw = weights
        self.node_vox = weights.grid.to_vox(np.asarray(points_m, float))
        self.opt = options or TrackOptions()
        g = weights.grid
        self.shape = np.asarray(g.shape)
        self.Xa = np.stack(np.unravel_index(weights.voxels, g.shape), 1).astype(np.float64)
        # solve windows (optionally with a minimum support); confidence and coverage over
        # the node's own elements (Eq. A.4) unless confidence_window == "solve"
        self.W = weights.with_min_support(points_m, self.opt.min_support_vox)
        self.Wc = weights.W if self.opt.confidence_window == "elements" else self.W
        self.w_total = np.asarray(self.Wc.sum(1)).ravel()
        # the same products in row blocks on the cores (`parallel`: identical to the bit)
        self._W, self._Wc = RowBlocks(self.W), RowBlocks(self.Wc)
        self.n = weights.n_nodes

    def start(self, volume: np.ndarray, U0_vox: np.ndarray | None = None):
        """Begin at `volume` (frame 0), with the nodes displaced by U0_vox (default 0)."""
        self.U = np.zeros((self.n, 3)) if U0_vox is None else np.array(U0_vox, float)
        self.v = np.zeros((self.n, 3))
        coef, grads = self._prepare(volume)
        pos = self.Xa + self.vw.interpolate(self.U)
        self.J, self.G, self.valid = self._sample(coef, grads, pos)

    def _prepare(self, volume):
        vol = np.asarray(volume, np.float32)
        if self.opt.presmooth_vox > 0:
            vol = ndimage.gaussian_filter(vol, self.opt.presmooth_vox)
        coef = ndimage.spline_filter(vol, order=3, output=np.float32, mode="mirror")
        # central differences of the samples (those of the spline coefficients, the exact
        # derivative of the interpolant, over-weight aliased speckle and converge slower)
        grads = np.gradient(vol)
        return coef, grads

    def _sample_next(self, coef, pos):
        inside = np.all((pos >= 1.0) & (pos <= self.shape - 2.0), axis=1)
        return map_coordinates(coef, pos, order=3, prefilter=False, mode="mirror"), inside

    def _sample(self, coef, grads, pos):
        valid = np.all((pos >= 1.0) & (pos <= self.shape - 2.0), axis=1)
        J = map_coordinates(coef, pos, order=3, prefilter=False, mode="mirror")
        G = np.stack([map_coordinates(gr, pos, order=1, mode="nearest") for gr in grads], 1)
        return J, G, valid

    def step(self, volume: np.ndarray):
        """Track from the current frame to `volume`.

        Returns
        -------
        v_vox : (n, 3) nodal motion from the current frame to `volume`, voxels (image axes)
        c : (n, 3) confidence in [0, 1] per image axis
        """
        opt = self.opt
        coef, grads = self._prepare(volume)
        v = self.v.copy() if opt.warm_start else np.zeros((self.n, 3))
        W, Wc = self._W, self._Wc
        base = self.Xa + self.vw.interpolate(self.U)          # voxels at frame k
        ok0 = self.valid
        G = self.G
        if opt.symmetric_gradient:
            # average with frame k+1's gradient where the warm start puts the tissue: the
            # noise of a frame's gradient is correlated with its (interpolated) values; the
            # two frames' correlations cancel to first order (no errors-in-variables bias)
            pos0 = base + self.vw.interpolate(v)
            G = 0.5 * (G + np.stack([map_coordinates(gr, pos0, order=1, mode="nearest") for gr in grads], 1))
        g = G * ok0[:, None]
        prod = np.empty((len(g), 6))
        for q, (a, b) in enumerate(_PAIRS):
            prod[:, q] = g[:, a] * g[:, b]
        S = W @ prod
        A = S[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)
        tr = np.trace(A, axis1=1, axis2=2)
        floor = 1e-9 * (tr.max() if tr.max() > 0 else 1.0)
        A = A + (opt.regularization * tr + floor)[:, None, None] * np.eye(3)
        Ainv = np.linalg.inv(A)
        cover = (Wc @ ok0.astype(float)) / np.maximum(self.w_total, 1e-300)
        node_pos = self.node_vox + self.U
        in_view = np.all((node_pos >= 0) & (node_pos <= self.shape - 1), axis=1)
        live = (cover >= opt.min_coverage) & in_view
        # confidence, Eq. A.4 (frame-k gradients over the voxels in view)
        c = Wc @ np.abs(g)
        if opt.confidence == "mean":
            c = c / np.maximum(Wc @ ok0.astype(float), 1e-300)[:, None]
        c[~live] = 0.0
        cmax = c.max()
        c = c / cmax if cmax > 0 else c
        # Stage 1, the Appendix: per-node translation (A.2-A.3), iterated with warping.
        # Frame k+1 is sampled once per voxel at the motion V interpolated from the nodes;
        # each node's rows are moved to its own translation by a first-order correction
        # with the frame-k gradient, I(p + v_n) ~ I(p + V) + G . (v_n - V), so
        # b_n = sum_i N g (J1 - J0 - G.V) + (sum_i N g G^T) v_n: sparse products only.
        J0 = self.J
        m_at = M = None
        for it in range(1, opt.max_iterations + 1):
            v_at = v
            vt = self.vw.interpolate(v)
            J1, inside = self._sample_next(coef, base + vt)
            m = (inside & ok0).astype(float)
            r = m * (J1 - J0 - np.einsum("ij,ij->i", G, vt))
            if m_at is None or not np.array_equal(m, m_at):     # the rows in view change rarely
                M = W @ np.column_stack([m * g[:, a_] * G[:, b_] for a_, b_ in _PAIRS])
                M = M[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)
                m_at = m
            b = W @ (g * r[:, None]) + np.einsum("nij,nj->ni", M, v)
            delta = -np.einsum("nij,nj->ni", Ainv, b)
            v = v + delta
            if (np.abs(delta[live]).max() if live.any() else 0.0) < opt.tol_vox:
                break
        self.v_local = v.copy()
        self.iterations = it
        # Stage 2: the interpolated motion as the model. Each strong node's window is
        # compared at the interpolated field V(p) itself, and the correction solved with the
        # node's own system (block Jacobi on the joint least-squares problem of all nodes):
        # the fixed point has no window-average bias for motion the mesh can represent.
        # Weak nodes keep their stage-1 values (nodes without data take their neighbours'),
        # so they cannot disturb their neighbours.
        strong = live & (c.min(1) >= opt.interpolated_min_confidence)
        if opt.interpolated_iterations > 0:
            v = self._fill(v, live)
        for _ in range(opt.interpolated_iterations):
            v_at = v
            J1, inside = self._sample_next(coef, base + self.vw.interpolate(v))
            self.iterations += 1
            b = W @ (g * ((J1 - J0) * inside)[:, None])
            delta = -np.einsum("nij,nj->ni", Ainv, b)
            delta[~strong] = 0.0
            v = v + delta
            if (np.abs(delta).max() if strong.any() else 0.0) < opt.tol_vox:
                break
        if opt.interpolated_iterations == 0:
            v[cover <= 0] = 0.0
        # frame k+1 where the material now is (where it was last sampled): next pair's start
        self.U = self.U + v_at
        pos = base + self.vw.interpolate(v_at)
        self.J, self.valid = J1, inside
        self.G = np.stack([map_coordinates(gr, pos, order=1, mode="nearest") for gr in grads], 1)
        self.v = v
        return v, c

    def _fill(self, v, known, sweeps: int = 20):
        """Nodes not `known` take the mean of their known (or already filled) neighbours
        (mesh adjacency), so nodes without data do not distort the interpolated motion."""
        A = self.vw.adjacency
        if A is None or known.all():
            return v
        v = v.copy()
        have = known.astype(float)
        for _ in range(sweeps):
            todo = have == 0
            if not todo.any():
                break
            cnt = A @ have
            new = todo & (cnt > 0)
            if not new.any():
                break
            v[new] = (A @ (v * have[:, None]))[new] / cnt[new, None]
            have[new] = 1.0
        return v
