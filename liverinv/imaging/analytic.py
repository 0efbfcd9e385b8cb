"""A smooth, indentation-like analytic motion on a mesh, written as a forward-run Dataset.

Used to develop and test the imaging chain independently of the finite-element engine:
the same variables and dims as `liverinv simulate` writes.
"""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

__all__ = ["indentation_field", "analytic_run", "triangle_depth"]


def triangle_depth(t, depth_m: float, rate_m_s: float) -> np.ndarray:
    """Load/unload ramp: 0 -> depth at `rate`, then back to 0 at the same rate."""
    t_half = depth_m / rate_m_s
    t = np.asarray(t, float)
    return np.clip(np.where(t <= t_half, rate_m_s * t, depth_m - rate_m_s * (t - t_half)), 0.0, depth_m)


def indentation_field(X, depth_m: float, height_m: float = 0.0303, width_m: float = 8e-3,
                      bulge: float = 0.25) -> np.ndarray:
    """Displacement (n, 3) m of a smooth punch-like field at reference points X (n, 3).

    ``u_z = -d s(z) g(r)``, ``u_r = bulge d s(z) (r / w) g(r)`` with ``s = (z/H)^2`` (zero and
    flat at the fixed bottom) and ``g = exp(-r^2 / (2 w^2))``.
    """
    X = np.asarray(X, float)
    r2 = X[:, 0] ** 2 + X[:, 1] ** 2
    s = np.clip(X[:, 2] / height_m, 0.0, None) ** 2
    g = np.exp(-0.5 * r2 / width_m ** 2)
    u = np.zeros_like(X)
    u[:, 2] = -depth_m * s * g
    u[:, 0] = bulge * depth_m * s * g * X[:, 0] / width_m
    u[:, 1] = bulge * depth_m * s * g * X[:, 1] / width_m
    return u


def analytic_run(points, cells, times, depth_m, **field_kw) -> xr.Dataset:
    """Forward-run Dataset (dims time, node, component, element, local) of the analytic
    field with indenter depth history `depth_m(times)`; force is a linear spring (18.3 N/m)
    stand-in."""
    times = np.asarray(times, float)
    depth = np.asarray(depth_m, float)
    u = np.stack([indentation_field(points, d, **field_kw) for d in depth])
    return xr.Dataset(
        {"indenter_depth": (("time",), depth, {"units": "m"}),
         "indenter_force": (("time",), 18.32 * depth, {"units": "N"}),
         "u": (("time", "node", "component"), u, {"units": "m"}),
         "X": (("node", "component"), np.asarray(points, float), {"units": "m"}),
         "cells": (("element", "local"), np.asarray(cells, np.int64))},
        coords={"time": ("time", times, {"units": "s"}), "component": ["x", "y", "z"]},
        attrs={"law": "analytic", "params": json.dumps(field_kw)})


def box_tet10(lo_m, hi_m, n: int):
    """A structured tet10 mesh of the box [lo_m, hi_m] with n cubes per side (6 Kuhn tets per
    cube, mid-edge nodes added); returns (points (N, 3), cells (ne, 10)) in meshio order
    (corners, then mid-edges of 01, 12, 20, 03, 13, 23). For tests and small examples."""
    lo, hi = np.asarray(lo_m, float), np.asarray(hi_m, float)
    ax = [np.linspace(lo[a], hi[a], n + 1) for a in range(3)]
    pts = np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    c = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
    corner = lambda d: idx[c[:, 0] + d[0], c[:, 1] + d[1], c[:, 2] + d[2]]
    v = [corner(((k >> 0) & 1, (k >> 1) & 1, (k >> 2) & 1)) for k in range(8)]
    kuhn = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]
    tets = np.concatenate([np.stack([v[a], v[b], v[c_], v[d]], 1) for a, b, c_, d in kuhn])
    edges = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]
    e = np.sort(np.stack([tets[:, [a, b]] for a, b in edges], 1), axis=2)   # (ne, 6, 2)
    uniq, inv = np.unique(e.reshape(-1, 2), axis=0, return_inverse=True)
    mid = 0.5 * (pts[uniq[:, 0]] + pts[uniq[:, 1]])
    cells = np.concatenate([tets, len(pts) + inv.reshape(-1, 6)], axis=1)
    return np.concatenate([pts, mid]), cells
