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
