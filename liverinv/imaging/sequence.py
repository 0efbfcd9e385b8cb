"""Ultrasound sequences of a simulated indentation: the truth motion imaged as speckle.

Two ways to make frame k from the truth displacement u_k at the mesh nodes:

``warp``
    The paper's way (section 2.3): the reference B-mode volume is warped by the deformation,
    ``I_k(x) = I_0(X)`` with ``x = X + u_k(X)``, by cubic B-spline interpolation. X(x) is found
    per voxel by the fixed-point iteration ``X <- x - u_k(X)``, with u_k resampled on the
    voxel grid (mesh hat functions inside the tissue, nearest tissue value outside) and
    interpolated trilinearly. Outside the tissue the image moves with the nearest tissue
    (so the PSF tails of the tissue echo move with it); the stand-off pad under the fixed
    bottom and water far from the tissue do not move.
``scatter``
    Physically: the tissue scatterers move with the tissue, ``x_s = X_s + u_k(X_s)``, and the
    frame is rendered again. Speckle then changes as in a real probe (axial phase, local
    strain), so no tracker can be exact on it.

Outside the tissue the background has its own texture and does not move: the stand-off pad
below the tissue (z < 0, weaker speckle) and water elsewhere (almost anechoic). Options:
additive Gaussian noise on the B-mode image (`bmode_noise`, std in B-mode units, both modes),
complex receiver noise before envelope detection (`noise_db` relative to the tissue reference
level, ``scatter`` only), and for ``scatter`` partial speckle decorrelation
(`decorrelation`, the fraction of each scatterer's complex amplitude renewed every frame).
All noise is independent between frames.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .kernels import cubic_mirror, inverse_map_at_voxels, trilinear
from .speckle import Transducer, log_compress, random_scatterers, render_iq
from .weights import VoxelWeights

log = logging.getLogger(__name__)

__all__ = ["ImagingOptions", "SpeckleScene", "inverse_map", "rendered_ahead", "warp_volume"]


@dataclass
class ImagingOptions:
    """How the sequence is imaged (SI units; see module docstring)."""

    mode: str = "warp"                 # "warp" or "scatter"
    seed: int = 0
    scatterers_per_cell: float = 5.0
    pad_echogenicity: float = 0.3      # amplitude std relative to tissue
    water_echogenicity: float = 0.01
    noise_db: float | None = None      # scatter mode: receiver noise relative to tissue level
    bmode_noise: float = 0.0           # std of additive noise on the B-mode image (0..1 units)
    decorrelation: float = 0.0         # scatter mode: fraction of amplitude renewed per frame
    transducer: Transducer = field(default_factory=Transducer)

    def __post_init__(self):
        if self.mode not in ("warp", "scatter"):
            raise ValueError(f"imaging mode must be 'warp' or 'scatter', not {self.mode!r}")
        if not 0.0 <= self.decorrelation <= 1.0:
            raise ValueError("decorrelation must lie in [0, 1]")
        if self.mode == "warp" and (self.noise_db is not None or self.decorrelation > 0):
            raise ValueError("noise_db and decorrelation apply to mode 'scatter'; "
                             "use bmode_noise with mode 'warp'")
        if self.bmode_noise < 0:
            raise ValueError("bmode_noise must be >= 0")


def _sample_grid(field_grid: np.ndarray, v: np.ndarray, order: int = 1) -> np.ndarray:
    """Values of a (*shape, c) grid field at continuous voxel coordinates v (m, 3) (beyond the
    grid: the edge values; order 1 by the compiled `kernels.trilinear`, scipy's to rounding)."""
    if order == 1:
        return trilinear(field_grid, v)
    return np.stack([ndimage.map_coordinates(field_grid[..., c], v.T, order=order, mode="nearest")
                     for c in range(field_grid.shape[-1])], axis=1)


#: iterations of the inverse map's fixed point in `warp_volume` (see `inverse_map`)
INVERSE_MAP_ITERATIONS = 6


def inverse_map(u_grid_vox: np.ndarray, x_vox: np.ndarray, iterations: int = INVERSE_MAP_ITERATIONS,
                at_voxels: np.ndarray | None = None) -> np.ndarray:
    """Reference position X (voxels) of current positions x (voxels), ``x = X + u(X)``, by the
    fixed-point iteration ``X <- x - u(X)`` (converges for displacement gradients < 1).

    Six iterations from X = x do not converge where the displacement is large and steep: on the
    model motion of the 100-frame warped PSR data (6 mm, 20 voxels axially) they were off the
    25-iteration map by up to 1.0 voxel at the peak frame (RMS over the grid 0.0085 voxel; 4e-4
    voxel at 4 voxels of motion). Three iterations from the previous frame's map were within 0.06-0.19
    voxel (RMS 0.0008-0.0016). Left as it is: every warped bundle made so far was rendered so, and
    `imaging.response` must render a model's motion exactly as its data were rendered."""
    X = x_vox.copy()
    if at_voxels is not None and iterations > 0:
        # x_vox are voxel centres (`at_voxels` their flat indices): the first iteration's
        # interpolation from X = x is the grid's own value, taken without interpolating
        # (the same numbers: linear weights 1 and 0), one sixth of the cost saved
        X = x_vox - u_grid_vox.reshape(-1, u_grid_vox.shape[-1])[at_voxels]
        iterations -= 1
    for _ in range(iterations):
        X = x_vox - _sample_grid(u_grid_vox, X)
    return X


def warp_volume(reference: np.ndarray, u_grid_vox: np.ndarray, coef: np.ndarray | None = None) -> np.ndarray:
    """`reference` warped by the displacement `u_grid_vox` (voxels, image axes, on the grid):
    ``I(x) = I_ref(X)`` with ``x = X + u(X)`` (`inverse_map`), cubic B-splines (`coef`: the
    reference's spline coefficients, if already computed); voxels that do not move keep their
    value."""
    g_shape = reference.shape
    if coef is None:
        coef = ndimage.spline_filter(np.asarray(reference, np.float32), order=3, output=np.float32, mode="mirror")
    # inverse_map(u, x, at_voxels=moving) at every voxel that moves, in one compiled pass
    moving, X = inverse_map_at_voxels(u_grid_vox, INVERSE_MAP_ITERATIONS, 1e-6)
    out = np.asarray(reference, np.float32).ravel().copy()
    out[moving] = cubic_mirror(coef, X)      # ndimage.map_coordinates(coef, X.T, order=3, mode="mirror")
    return out.reshape(g_shape)


class SpeckleScene:
    """The tissue, its surroundings and the probe: renders frames for nodal displacements.

    Parameters
    ----------
    weights : VoxelWeights
        Hat-function weights of the truth mesh on the image grid (locates the tissue).
    options : ImagingOptions
    """

    def __init__(self, weights: VoxelWeights, options: ImagingOptions):
        self.vw, self.opt, self.grid = weights, options, weights.grid
        g, tr = self.grid, options.transducer
        self.rng = np.random.default_rng(options.seed)
        margin = np.asarray(tr.sigma_m) * (tr.truncate_sigmas + 1)
        corners = g.to_m(np.array([[i, j, k] for i in (0, g.shape[0] - 1)
                                   for j in (0, g.shape[1] - 1) for k in (0, g.shape[2] - 1)]))
        lo, hi = corners.min(0) - margin.max(), corners.max(0) + margin.max()
        pos, amp = random_scatterers(self.rng, lo, hi, options.scatterers_per_cell, tr)
        mask = self.vw.mask().astype(np.float32)
        in_tissue = ndimage.map_coordinates(mask, g.to_vox(pos).T, order=1, mode="nearest") > 0.5
        # scatterers beyond the grid faces: extend the tissue test by the nearest voxel
        self.tissue_pos, self.tissue_amp = pos[in_tissue], amp[in_tissue].astype(complex)
        bg_pos, bg_amp = pos[~in_tissue], amp[~in_tissue]
        below = bg_pos[:, 2] < 0.0
        bg_amp = bg_amp * np.where(below, options.pad_echogenicity, options.water_echogenicity)
        self.bg_iq = render_iq(g, bg_pos, bg_amp, tr)
        self.ref_iq = render_iq(g, self.tissue_pos, self.tissue_amp.real, tr)
        self.reference_level = float(np.percentile(np.abs(self.ref_iq.ravel()[self.vw.voxels]), 99.0))
        if options.mode == "warp":
            self.ref_bmode = log_compress(self.ref_iq + self.bg_iq, self.reference_level,
                                          tr.dynamic_range_db)
            self._coef = ndimage.spline_filter(self.ref_bmode, order=3, output=np.float32,
                                               mode="mirror")
        log.info("speckle scene: %d tissue and %d background scatterers", len(self.tissue_pos),
                 len(bg_pos))

    @property
    def stateless(self) -> bool:
        """Whether frames are independent of the order they are made in (warped volumes
        without B-mode noise: no random draw per frame), so several may render at once."""
        return self.opt.mode == "warp" and self.opt.bmode_noise == 0

    def frame(self, u_nodes_m: np.ndarray) -> np.ndarray:
        """B-mode volume (float32 in [0, 1]) for nodal displacements `u_nodes_m` (n, 3) m."""
        g, opt = self.grid, self.opt
        u_grid = self.vw.to_grid(g.vec_to_vox(u_nodes_m))          # voxels, image axes
        if opt.mode == "warp":
            out = warp_volume(self.ref_bmode, u_grid, self._coef)
            if opt.bmode_noise > 0:
                out = out + opt.bmode_noise * self.rng.standard_normal(g.shape)
            return np.clip(out, 0.0, 1.0).astype(np.float32)
        else:
            if opt.decorrelation > 0:
                new = self.rng.standard_normal(len(self.tissue_amp)) * np.exp(
                    2j * np.pi * self.rng.random(len(self.tissue_amp)))
                self.tissue_amp = (np.sqrt(1 - opt.decorrelation) * self.tissue_amp
                                   + np.sqrt(opt.decorrelation) * new)
            v = g.to_vox(self.tissue_pos)
            xs = g.to_m(v + _sample_grid(u_grid, v))
            iq = render_iq(g, xs, self.tissue_amp, opt.transducer)
        iq = iq + self.bg_iq
        if opt.noise_db is not None:
            s = self.reference_level * 10 ** (opt.noise_db / 20) / np.sqrt(2)
            iq = iq + s * (self.rng.standard_normal(g.shape) + 1j * self.rng.standard_normal(g.shape))
        out = log_compress(iq, self.reference_level, opt.transducer.dynamic_range_db)
        if opt.bmode_noise > 0:
            out = np.clip(out + opt.bmode_noise * self.rng.standard_normal(g.shape), 0, 1)
        return out.astype(np.float32)


def rendered_ahead(render, items, stateless: bool = False):
    """``render(item)`` for each of `items`, in order, computed in worker threads a few items
    before they are taken, so that rendering (interpolation that releases the GIL) runs on the
    second core while the caller tracks or writes the previous volume. One worker, the calls in
    order, so that a scene's random draws come out as in a plain loop; two at once when the
    `render` is `stateless` (`SpeckleScene.stateless`, a warp without noise)."""
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    workers, ahead = (2, 3) if stateless else (1, 2)
    items, end = iter(items), object()
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="render") as pool:
        pending = deque(pool.submit(render, it) for _, it in zip(range(ahead), items))
        while pending:
            done = pending.popleft()
            nxt = next(items, end)
            if nxt is not end:
                pending.append(pool.submit(render, nxt))
            yield done.result()
