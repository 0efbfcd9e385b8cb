r"""Mechanically regularized registration of tracked motion (seed paper section 2.2, Eqs. 1-3).

Regularization springs tie the free nodal dofs of the finite-element model to the tracked
motion: the free end of the spring at node i, direction j, sits at the accumulated tracked
displacement U_OF,ij(t), and its stiffness is (Eq. 2)

    k_ij = beta K_ij c_ij,

K_ij the diagonal of the global stiffness matrix at the reference state (u = 0) and c_ij the
tracking confidence in [0, 1]. The solver minimizes strain energy plus the spring energy
(Eq. 1) U_S = 1/2 sum k_ij (U_OF,ij - u_FEM,ij)^2 at every frame, with the indenter driven
by its measured depth (displacement control); u_FEM is the registered, mechanically
admissible field. The springs' normalized energy (Eq. 3)

    Phi = sum_i sum_j (1/2 k_ij d_ij^2) / (1/2 beta K_ij) = sum_i sum_j c_ij d_ij^2,
    d = U_OF - u_FEM,

measures the image/model agreement (m^2). Constrained dofs (fixed support, the footprint
u_z tied to the punch, pressure unknowns of biphasic laws) carry no spring.

The springs are a wrapper (`Springs`) around any engine model (`Indentation`, `Biphasic`):
it adds k (u - U_OF(t)) to the reduced residual and diag(k) to the tangent, and the solver
tells it the time of each (sub-)step through `set_time`; targets and stiffnesses are
interpolated linearly in time between frames.

Choice of beta: for a displacement pattern with stiffness lambda per node (K u = lambda u),
the springs pass the pattern by the factor beta c K / (lambda + beta c K). Smooth patterns
(wavelength of many elements) have lambda << K and follow the tracked motion; node-to-node
noise has lambda ~ K and is passed by beta c / (1 + beta c). `DEFAULT_BETA` = 1 makes a fully
confident spring as stiff as its node: node-scale noise at c = 1 is halved, smooth motion is
kept, and weakly tracked nodes (c << 1) follow the mechanics. It is the balance for a model
that is not exactly right: on a small synthetic case (630 nodes) registered with a 10x wrong
bulk compliance, beta = 1 gave the smallest RMS error over all nodes (beta 0.1 and 10: 1.8x
larger) and at the low-confidence nodes. With an exact model smaller beta is always better
(beta -> 0 is the pure forward solution driven by the indenter); raise beta to trust the
images more. Eq. 3 divides the spring energy by beta, but u_FEM, hence Phi, still depends
on it.

Example
-------
>>> reg = register_flow(ForwardModel(mesh), "elastic", params, flow, t_ind, depth)  # doctest: +SKIP
>>> reg.u_fem.shape, reg.phi.shape                                             # doctest: +SKIP
((n_frames, n_nodes, 3), (n_frames,))
"""

from __future__ import annotations

import logging
import time as _time
from dataclasses import dataclass, field

import numpy as np

from ..fem.solver import NewtonOptions, solve_history

__all__ = ["DEFAULT_BETA", "Springs", "Registration", "spring_dofs", "nodal_stiffness",
           "normalized_energy", "accumulate", "register", "register_flow",
           "registration_dataset"]

log = logging.getLogger(__name__)

DEFAULT_BETA = 1.0


def spring_dofs(model) -> np.ndarray:
    """(n_nodes, 3) reduced unknown of each nodal dof that can carry a spring, -1 where the
    dof is constrained (fixed, tied to the punch)."""
    n3 = 3 * model.space.mesh.n_nodes
    idx = np.asarray(model.asm.index[:n3]).copy()
    idx[(idx < 0) | (idx >= model.n_free)] = -1
    return idx.reshape(-1, 3)


def nodal_stiffness(model, dt=1.0) -> np.ndarray:
    """(n_nodes, 3) diagonal of the reference (u = 0) tangent, N/m; 0 at constrained dofs.
    `dt` is the step length the tangent is taken for (it matters for viscous laws)."""
    ev = model.evaluate(np.zeros(model.n_red), dt, model.new_state(), tangent=True)
    idx = spring_dofs(model)
    diag = ev.K.diagonal()
    return np.where(idx >= 0, diag[np.maximum(idx, 0)], 0.0)


def normalized_energy(u_of, u_fem, c) -> np.ndarray:
    """Eq. 3 per frame: sum over nodes and components of c (u_OF - u_FEM)^2, m^2."""
    d = np.asarray(u_of) - np.asarray(u_fem)
    return np.einsum("...ij,...ij->...", np.asarray(c), d * d)


def accumulate(u_of) -> np.ndarray:
    """Accumulated tracked displacement at every frame (frame 0 = 0) from frame-to-frame
    motion (K, n, 3) -> (K + 1, n, 3)."""
    u_of = np.asarray(u_of, float)
    return np.concatenate([np.zeros((1, *u_of.shape[1:])), np.cumsum(u_of, axis=0)])


class Springs:
    """An engine model with regularization springs on its free nodal dofs.

    Parameters
    ----------
    model : `Indentation` or `Biphasic` (anything with `asm`, `n_free`, `evaluate`, ...)
    times : (T,) s, increasing frame times
    targets : (T, n_nodes, 3) m, spring free-end positions (displacements) at the frames
    stiffness : (T, n_nodes, 3) N/m, spring stiffnesses at the frames (ignored at
        constrained dofs)

    Everything but `evaluate` and `set_time` is the wrapped model's.
    """

    def __init__(self, model, times, targets, stiffness):
        self.model = model
        self.times = np.asarray(times, float)
        idx = spring_dofs(model)
        on = idx >= 0
        self.dofs = idx[on]                                   # reduced unknowns with springs
        self._targets = np.asarray(targets, float)[:, on]     # (T, n_springs)
        self._k = np.asarray(stiffness, float)[:, on]
        if len(self.times) < 2 or not len(self.times) == len(self._targets) == len(self._k):
            raise ValueError("times, targets and stiffness need the same number (>= 2) of frames")
        asm = model.asm
        diag = np.full(model.n_red, -1, dtype=np.int64)
        d = np.nonzero(asm.rows == asm.indices)[0]
        diag[asm.rows[d]] = d
        self._diag_pos = diag[self.dofs]                      # CSR data positions of K[i, i]
        self.set_time(self.times[0])

    def __getattr__(self, name):  # only called for names Springs does not define
        if name == "model":
            raise AttributeError(name)
        return getattr(self.model, name)

    def set_time(self, t):
        """Targets and stiffnesses at time t (linear between frames, constant outside)."""
        ts = self.times
        j = int(np.clip(np.searchsorted(ts, t) - 1, 0, len(ts) - 2))
        w = float(np.clip((t - ts[j]) / (ts[j + 1] - ts[j]), 0.0, 1.0))
        self.t = t
        self.target = (1 - w) * self._targets[j] + w * self._targets[j + 1]
        self.k = (1 - w) * self._k[j] + w * self._k[j + 1]

    def spring_force(self, q) -> np.ndarray:
        """k (u - target) on the spring dofs, N."""
        return self.k * (q[self.dofs] - self.target)

    def evaluate(self, q, dt, state, tangent=True):
        ev = self.model.evaluate(q, dt, state, tangent=tangent)
        ev.r[self.dofs] += self.spring_force(q)      # one spring per dof: no repeated index
        if ev.K is not None:
            ev.K.data[self._diag_pos] += self.k
        return ev

    def energy(self, q) -> float:
        """Spring energy U_S (Eq. 1), J."""
        d = q[self.dofs] - self.target
        return float(0.5 * self.k @ (d * d))


@dataclass
class Registration:
    time: np.ndarray        # (T,) s, frame times
    depth: np.ndarray       # (T,) m, punch depth driven
    force: np.ndarray       # (T,) N, punch force of the registered state
    u_fem: np.ndarray       # (T, n, 3) m, registered displacement
    u_of: np.ndarray        # (T, n, 3) m, accumulated tracked displacement
    c: np.ndarray           # (T, n, 3) spring confidence (0 at constrained dofs)
    K: np.ndarray           # (n, 3) N/m, reference nodal stiffness (0 at constrained dofs)
    beta: float
    phi: np.ndarray         # (T,) m^2, Eq. 3
    energy: np.ndarray      # (T,) J, Eq. 1
    timing: dict = field(default_factory=dict)

    @property
    def phi_total(self) -> float:
        return float(self.phi.sum())


def register(forward, law, params, times, u_of, c_of, t_ind, depth, beta=DEFAULT_BETA,
             options: NewtonOptions | None = None) -> Registration:
    """Registered displacement at every frame.

    Parameters
    ----------
    forward : `liverinv.forward.ForwardModel` on the mesh the motion was tracked on
    law, params : law name and its parameters
    times : (T,) s, frame times (frame 0 shows the unloaded tissue)
    u_of : (T - 1, n, 3) m, tracked frame-to-frame motion (frame k -> k + 1)
    c_of : (T - 1, n, 3) confidence in [0, 1] of each frame pair; the springs at frame
        k + 1 take the confidence of pair k, the springs at frame 0 that of pair 0
    t_ind, depth : indenter record (s, m); the punch depth is interpolated at the frames
    beta : regularization coefficient of Eq. 2
    options : NewtonOptions
    """
    times = np.asarray(times, float)
    u_of, c_of = np.asarray(u_of, float), np.asarray(c_of, float)
    n = forward.mesh.n_nodes
    if u_of.shape != c_of.shape or u_of.ndim != 3 or u_of.shape[1:] != (n, 3):
        raise ValueError(f"tracked motion {u_of.shape} and confidence {c_of.shape} must both be "
                         f"(frame pairs, {n} nodes, 3)")
    if len(times) < 2 or len(times) != len(u_of) + 1:
        raise ValueError(f"{len(times)} frame times for {len(u_of)} frame pairs")
    if not 0 < beta < np.inf:
        raise ValueError(f"beta must be a positive number (got {beta})")
    if times[0] < t_ind[0] - 1e-9 or times[-1] > t_ind[-1] + 1e-9:
        raise ValueError("frame times must lie within the indenter record")
    d_drive = np.interp(times, t_ind, depth)
    if abs(d_drive[0]) > 0.01 * max(np.abs(d_drive).max(), 1e-12):
        log.warning("punch depth %.3g m at the first frame: the registration takes it as unloaded",
                    d_drive[0])
    d_drive[0] = 0.0
    targets = accumulate(u_of)
    c = np.clip(np.concatenate([c_of[:1], c_of]), 0.0, 1.0)
    model = forward.model(law, params)
    t0 = _time.perf_counter()
    K = nodal_stiffness(model, dt=times[1] - times[0])
    t_stiffness = _time.perf_counter() - t0
    c = np.where(K > 0, c, 0.0)
    springs = Springs(model, times, targets, beta * K * c)
    energy = np.zeros(len(times))

    def record(k, q, ev):
        energy[k] = springs.energy(q)

    h = solve_history(springs, times, d_drive, "displacement", options, record)
    timing = dict(h.timing, stiffness_s=t_stiffness)
    phi = normalized_energy(targets, h.u, c)
    log.info("registered %d frames (beta %g) in %.1f s; Phi = %.3e m^2", len(times), beta,
             timing["wall_s"], phi.sum())
    return Registration(times, h.depth, h.force, h.u, targets, c, K, float(beta), phi, energy, timing)


def register_flow(forward, law, params, flow, t_ind, depth, beta=DEFAULT_BETA,
                  options: NewtonOptions | None = None) -> Registration:
    """`register` on a flow Dataset of `liverinv track` (its `frame_time`, `u_of`, `c_of`)."""
    if flow.sizes["node"] != forward.mesh.n_nodes or not np.allclose(
            flow["X"].values, forward.mesh.points, rtol=0, atol=1e-9):
        raise ValueError(f"the flow's {flow.sizes['node']} nodes are not the mesh's "
                         f"{forward.mesh.n_nodes}: register on the mesh the flow was tracked on")
    times = flow["frame_time"].values[: flow.sizes["frame"] + 1]
    return register(forward, law, params, times, flow["u_of"].values, flow["c_of"].values,
                    t_ind, depth, beta, options)


def registration_dataset(reg: Registration, mesh, law, params, attrs=None):
    """The registration as a self-contained Dataset (the `liverinv register` file)."""
    import xarray as xr

    from ..fileio import provenance
    tnc = ("time", "node", "component")
    ds = xr.Dataset(
        data_vars=dict(
            u_fem=(tnc, reg.u_fem, {"units": "m", "long_name": "registered nodal displacement (u_FEM)"}),
            u_of=(tnc, reg.u_of, {"units": "m", "long_name": "accumulated tracked displacement (U_OF), "
                                                             "free ends of the springs"}),
            c=(tnc, reg.c, {"units": "1", "long_name": "spring confidence c_OF (0 at constrained dofs)"}),
            K=(("node", "component"), reg.K, {"units": "N/m", "long_name": "reference nodal stiffness "
                                              "(diagonal of the u = 0 tangent; 0 at constrained dofs)"}),
            phi=("time", reg.phi, {"units": "m^2", "long_name": "normalized spring energy, Eq. 3"}),
            phi_total=((), reg.phi_total, {"units": "m^2", "long_name": "Eq. 3 summed over the frames"}),
            spring_energy=("time", reg.energy, {"units": "J", "long_name": "spring energy U_S, Eq. 1"}),
            indenter_depth=("time", reg.depth, {"units": "m", "long_name": "punch depth driven (measured)"}),
            indenter_force=("time", reg.force, {"units": "N", "long_name": "punch force of the registered state"}),
            beta=((), reg.beta, {"units": "1", "long_name": "regularization coefficient, Eq. 2"}),
            X=(("node", "component"), mesh.points, {"units": "m", "long_name": "reference node coordinates"}),
            cells=(("element", "local"), mesh.cells, {"long_name": "tet10 connectivity (meshio/VTK order)"}),
        ),
        coords=dict(time=("time", reg.time, {"units": "s"}), component=["x", "y", "z"]),
    )
    ds.attrs = provenance(law=law, params=params, beta=reg.beta, control="displacement",
                          solver=dict(reg.timing), **(attrs or {}))
    return ds
