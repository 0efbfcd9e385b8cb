"""Where a fit fails: its volumetric misfit Phi_vol split into parts a person can read.

Each split is {part: share} with shares summing to 1:

* ``region`` (under the punch, near the rim, far field), ``depth`` (thirds of the tissue
  height, from the bottom), ``time`` (loading, hold, unloading: the indenter's rate above,
  within or below 5 % of its largest magnitude) and ``component`` (axial, radial, tangential
  about the punch axis): shares of Phi_vol;
* ``strain_rate`` (low, middle, high): shares of Phi_vol over the (frame pair, node) samples
  binned by terciles of the model's local strain rate there, so each bin holds a third of the
  tracked samples and a share above 1/3 says the misfit gathers where the tissue deforms fast (a rate
  effect) or slowly;
* ``gradient`` (volumetric, deviatoric): shares of the squared norm of the residual's velocity
  gradient, L = grad(v_OF - v_FEM), split into its trace part (tr L)^2 / 3 (a change of volume
  the model misses) and its deviatoric part |dev L|^2 (a change of shape), confidence-weighted.
  ``gradient_data`` is the same split of the tracked motion itself, the reference to read it
  against: a residual more volumetric than the data points at a volumetric effect (bulk
  relaxation, Darcy flow, a nonlinear bulk term).

Velocity gradients at the tracked nodes come from a local linear least-squares fit over each
node's `N_NEIGHBOURS` nearest tracked nodes (confidence-weighted), so the split needs no mesh
connectivity and works for a flow tracked on any mesh.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["misfit_splits", "local_gradients", "SPLIT_MEANING"]

N_NEIGHBOURS = 12
HOLD_RATE = 0.05      # |depth rate| below this fraction of its largest value: a hold

#: what each split's shares are shares of (for tables and figure axes)
SPLIT_MEANING = {"region": "Phi_vol", "depth": "Phi_vol", "time": "Phi_vol", "component": "Phi_vol",
                 "strain_rate": "Phi_vol", "gradient": "residual velocity gradient (squared norm)",
                 "gradient_data": "tracked velocity gradient (squared norm)"}


def local_gradients(X, weights=None, k=N_NEIGHBOURS):
    """(neighbours (N, k), operator (N, 3, k)): the gradient at each of the points X (N, 3) of
    a field f sampled at them is ``operator[n] @ f[neighbours[n]]``, a weighted linear
    least-squares fit over its k nearest points (weights (N,): 0 leaves a point out)."""
    X = np.asarray(X, float)
    k = min(k, len(X))
    _, nb = cKDTree(X).query(X, k)
    w = np.ones(len(X)) if weights is None else np.asarray(weights, float)
    dX = X[nb] - X[:, None, :]
    h = np.sqrt((dX ** 2).sum(axis=2).mean(axis=1))                                  # (N,) local spread
    h = np.where(h > 0, h, 1.0)
    A = np.concatenate([np.ones(nb.shape + (1,)), dX / h[:, None, None]], axis=2)     # (N, k, 4)
    AtW = A.transpose(0, 2, 1) * w[nb][:, None, :]                                    # (N, 4, k)
    M = AtW @ A
    ok = np.linalg.cond(M) < 1e10
    op = np.zeros((len(X), 3, k))
    op[ok] = np.linalg.solve(M[ok], AtW[ok])[:, 1:, :] / h[ok, None, None]
    return nb, op


def _gradient_field(nb, op, v):
    """(K, N, 3, 3) L_ij = d v_i / d x_j of the (K, N, 3) field v."""
    return np.einsum("njk,tnki->tnij", op, v[:, nb, :])


def _vol_dev(L, w):
    tr = np.trace(L, axis1=-2, axis2=-1)
    vol = tr ** 2 / 3.0
    tot = (L ** 2).sum(axis=(-2, -1))
    vol, tot = float((w * vol).sum()), float((w * tot).sum())
    return {"volumetric": vol / tot, "deviatoric": 1.0 - vol / tot} if tot > 0 else None


def misfit_splits(objective, residual, v_fem=None, punch_radius=0.006) -> dict:
    """{split: {part: share}} of the residual vector of `objective` (see the module doc);
    `v_fem` (K, N, 3), the model's velocities at the tracked nodes, gives the strain-rate and
    gradient splits."""
    d = objective.data
    K, N = objective.K, objective.N
    rv = np.asarray(residual)[: objective.v_of.size].reshape(K, N, 3)
    X = objective.forward.mesh.points if d.X is None else np.asarray(d.X)
    total = float((rv ** 2).sum())
    if total <= 0:
        return {}
    r = np.hypot(X[:, 0], X[:, 1])
    a = punch_radius
    e2 = rv ** 2
    node = e2.sum(axis=(0, 2))
    region = {"under the punch": r < a, "near the rim": (r >= a) & (r < 2 * a), "far field": r >= 2 * a}
    z = X[:, 2]
    cuts = np.linspace(z.min(), z.max(), 4)
    depth = {"bottom third": z < cuts[1], "middle third": (z >= cuts[1]) & (z < cuts[2]), "top third": z >= cuts[2]}
    frame = e2.sum(axis=(1, 2))
    td, dd = objective.t_drive, objective.d_drive
    rate = np.interp(0.5 * (d.t0 + d.t1), 0.5 * (td[1:] + td[:-1]), np.diff(dd) / np.diff(td))
    level = HOLD_RATE * np.abs(rate).max() if np.abs(rate).max() > 0 else np.inf
    window = {"loading": rate > level, "hold": np.abs(rate) <= level, "unloading": rate < -level}
    window = {k: m for k, m in window.items() if m.any()}
    with np.errstate(invalid="ignore", divide="ignore"):
        er = np.where(r[:, None] > 0, np.stack([X[:, 0], X[:, 1]], 1) / r[:, None], [1.0, 0.0])
    radial = (rv[..., 0] * er[:, 0] + rv[..., 1] * er[:, 1]) ** 2
    tangential = (-rv[..., 0] * er[:, 1] + rv[..., 1] * er[:, 0]) ** 2
    comp = {"axial": float(e2[..., 2].sum()), "radial": float(radial.sum()), "tangential": float(tangential.sum())}
    out = {"region": {k: float(node[m].sum() / total) for k, m in region.items()},
           "depth": {k: float(node[m].sum() / total) for k, m in depth.items()},
           "time": {k: float(frame[m].sum() / total) for k, m in window.items()},
           "component": {k: v / total for k, v in comp.items()}}
    if v_fem is None:
        return out
    c = np.asarray(d.c_of).mean(axis=2)                                  # (K, N)
    tracked = (c > 0)[..., None]
    nb, op = local_gradients(X, tracked.any(axis=0)[:, 0].astype(float))
    L_model = _gradient_field(nb, op, np.asarray(v_fem))
    D = 0.5 * (L_model + np.swapaxes(L_model, -1, -2))
    rate_mag = np.sqrt((D ** 2).sum(axis=(-2, -1)))                      # (K, N), 1/s
    lo, hi = np.quantile(rate_mag[tracked[..., 0]], [1 / 3, 2 / 3]) if tracked.any() else (0.0, 0.0)
    pair = e2.sum(axis=2)
    bins = {"low": rate_mag <= lo, "middle": (rate_mag > lo) & (rate_mag <= hi), "high": rate_mag > hi}
    out["strain_rate"] = {k: float(pair[m].sum() / total) for k, m in bins.items()}
    v_of = objective.v_of
    # where a node was not tracked its residual is taken as 0 (the tracked motion as the model's)
    for name, field in (("gradient", np.where(tracked, v_of - v_fem, 0.0)),
                        ("gradient_data", np.where(tracked, v_of, v_fem))):
        split = _vol_dev(_gradient_field(nb, op, field), c)
        if split is not None:
            out[name] = split
    return out
