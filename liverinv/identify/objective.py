r"""The model/experiment misfit of the seed paper (Eqs. 4-5), as a scalar and as residuals.

For a law and parameters, the forward model is driven by the measured indenter force
history (force control, interpolated at t = 0 and the frame times) on the inverse mesh. With frame pairs k (times t0_k -> t1_k) of the
tracked motion u_OF and confidence c_OF at N nodes:

    Phi_vol = 1/(N K) sum_k sum_i sum_j c_kij (v_OF,kij - v_FEM,kij)^2,   v = u / (t1 - t0)
    Phi_ind = 1/M sum_s (ddot_exp,s - ddot_model,s)^2   (indenter velocity over the M
                                                          intervals between driving times)
    Phi     = Phi_vol + Phi_ind

(velocities in m/s, Phi in m^2/s^2). The model's nodal motion between frames is the
difference of its displacement interpolated linearly in time at t1_k and t0_k. The residual
vector r = [sqrt(c/(N K)) (v_OF - v_FEM), (ddot_exp - ddot_model)/sqrt(M)] has |r|^2 = Phi.

The model mesh may differ from the mesh the motion was tracked on (e.g. one refined at the
punch rim, where the contact stress is singular): the model's displacement is then
interpolated with its quadratic shape functions at the tracked nodes (`Measurements.X`).

Observation operator (optional, `observation=`): the model's motion is compared as the
tracker would have reported it, i.e. window-averaged like the tracked motion
(`imaging.observation.TrackingObservation`), instead of at the nodes.

Noise-aware objective (`noise=` a `noise.NoiseModel`; the default of `liverinv fit`): a
Gaussian likelihood. The model is driven by the measured depth (displacement control; the
record smoothed by GCV splines between the kinks of the load history, `noise.smooth_record`:
the reversals and the ends of a hold, `noise.kinks`, which are driving times too) and
compared with the measured force at every indenter sample (the model's force interpolated
quadratically between driving times, not across a kink); the tracked motion is compared
frame pair by frame pair, each residual divided by its standard deviation::

    r_vol = sqrt(c) (u_OF - u_FEM) / sigma_track         (per frame pair, node, direction)
    r_ind = (F_exp,s - F_model(t_s)) / sigma_F            (per indenter sample s)
    Phi = Phi_vol + Phi_ind = sum r^2                     (dimensionless, -2 log L + const)

Force control with the raw force (the paper's way) lets 13 mN of force noise make the
modelled depth jitter near zero load, where the tissue is soft; a stiffer law jitters less
and wins. Relative to its range the depth record is 50 times quieter than the force (on the
issue-11 informative case: 3.9 um of 5.9 mm, 6.6e-4, against 13 mN of 0.36 N, 3.6e-2), so
driving by it and fitting the force removes the jitter from both terms.
"""

from __future__ import annotations

import logging
import time as _time
from dataclasses import dataclass, replace

import numpy as np

from ..fem.sensitivity import Sensitivity
from ..fem.solver import ConvergenceError, NewtonOptions, solve_history
from ..forward import ForwardModel
from .noise import kinks, piecewise_quadratic, smooth_record

__all__ = ["Measurements", "Objective", "Evaluation"]

log = logging.getLogger(__name__)


@dataclass
class Measurements:
    """What the objective compares with: indenter samples and tracked nodal motion."""
    t_ind: np.ndarray     # (M,) s, starts at 0
    depth: np.ndarray     # (M,) m, measured punch depth
    force: np.ndarray     # (M,) N, measured punch force (drives the model)
    t0: np.ndarray        # (K,) s, start of each tracked frame pair
    t1: np.ndarray        # (K,) s, end of each tracked frame pair
    u_of: np.ndarray      # (K, N, 3) m, tracked motion from t0 to t1
    c_of: np.ndarray      # (K, N, 3) confidence in [0, 1]
    X: np.ndarray | None = None  # (N, 3) m, reference positions of the tracked nodes

    @classmethod
    def from_flow(cls, flow, t_ind, depth, force):
        """From a flow Dataset (`liverinv track`) and indenter samples."""
        return cls(np.asarray(t_ind, float), np.asarray(depth, float), np.asarray(force, float),
                   flow.time_start.values, flow.time_end.values, flow.u_of.values, flow.c_of.values,
                   flow.X.values if "X" in flow else None)

    def every(self, m: int) -> "Measurements":
        """The frame pairs merged `m` at a time (the last block may hold fewer): the motion
        summed and the confidence ``c = m / sum(1 / c_i)`` (0 where any pair has 0), so that
        with the tracking noise level times sqrt(m) each merged pair carries the variance of
        its sum, sigma^2 sum(1 / c_i); the indenter record unchanged. For a search on fewer
        frames (`Objective.every`)."""
        m = int(m)
        if m < 1:
            raise ValueError(f"merge at least 1 frame pair, not {m}")
        if m == 1:
            return self
        if not np.allclose(self.t1[:-1], self.t0[1:], rtol=0, atol=1e-9):
            raise ValueError("frame pairs can be merged only when each starts where the last ended")
        starts = np.arange(0, len(self.t0), m)
        ends = np.minimum(starts + m, len(self.t0))
        inv = np.where(self.c_of > 0, 1.0 / np.where(self.c_of > 0, self.c_of, 1.0), np.inf)
        return replace(self, t0=self.t0[starts], t1=self.t1[ends - 1], u_of=np.add.reduceat(self.u_of, starts, axis=0),
                       c_of=m / np.add.reduceat(inv, starts, axis=0))

    @classmethod
    def from_run(cls, run, frames=None, confidence=1.0):
        """Noise-free synthetic measurements from a forward run Dataset (its nodes must be
        the inverse mesh's): the exact frame-to-frame motion with uniform confidence."""
        t = run.time.values
        u = run.u.values
        idx = np.arange(len(t)) if frames is None else np.asarray(frames)
        u_of = u[idx[1:]] - u[idx[:-1]]
        return cls(t, run.indenter_depth.values, run.indenter_force.values, t[idx[:-1]], t[idx[1:]],
                   u_of, np.full(u_of.shape, float(confidence)), run.X.values if "X" in run else None)


@dataclass
class Evaluation:
    params: dict
    ok: bool
    phi: float
    phi_vol: float
    phi_ind: float
    rms_depth: float = np.nan      # m, RMS indenter displacement error
    rms_axial: float = np.nan      # m, RMS axial nodal displacement error (confident nodes)
    rms_force: float = np.nan      # N, RMS indenter force error (noise-aware objective)
    wall_s: float = 0.0
    message: str = ""
    residual: np.ndarray | None = None
    v_fem: np.ndarray | None = None   # (K, N, 3) model nodal velocities
    iterations: int = 0
    jacobian: np.ndarray | None = None  # (n_residuals, k) d residual / d direction, if asked
    model_time: np.ndarray | None = None   # s, the driving times
    model_depth: np.ndarray | None = None  # m, the model's indenter depth at them
    model_force: np.ndarray | None = None  # N, the model's indenter force at them


class Objective:
    """Phi(params) of one law on one data set.

    Parameters
    ----------
    forward : ForwardModel on the inverse mesh
    law : law name
    data : Measurements
    fixed : parameters held fixed (not identified), merged into every evaluation
    options : NewtonOptions of the forward solves
    confidence_floor : nodes with c_z below it do not count in the RMS displacement figure
    outside_tol : tracked nodes may lie this far (m) outside the model mesh, where the
        model's field is extrapolated (curved boundaries discretized differently by the two
        meshes); farther is an error
    observation : optional linear map of the model's nodal field (..., n_model, 3) to what
        the tracker would report at the tracked nodes (..., N, 3), e.g.
        `imaging.observation.TrackingObservation`; default: the field at the tracked nodes
    """

    def __init__(self, forward: ForwardModel, law: str, data: Measurements, fixed=None,
                 options: NewtonOptions | None = None, confidence_floor=0.1, outside_tol=2e-3,
                 observation=None, noise=None):
        self.forward, self.law, self.data = forward, law, data
        self.observation, self.outside_tol = observation, outside_tol
        self.fixed = dict(fixed or {})
        self.options = options or NewtonOptions()
        self.confidence_floor = confidence_floor
        self.K, self.N = data.u_of.shape[:2]
        self._solved = {}      # the last few solves' nodal histories by their parameters (`solution`)
        if observation is None:
            self.to_data = self._interpolation(forward.mesh, data, outside_tol)
        elif (observation.N, observation.n_model) != (self.N, forward.mesh.n_nodes):
            raise ValueError(f"observation maps {observation.n_model} model nodes to {observation.N} "
                             f"tracked nodes; the model mesh has {forward.mesh.n_nodes}, the data {self.N}")
        else:
            self.to_data = observation
        dt_f = data.t1 - data.t0
        if np.any(dt_f <= 0):
            raise ValueError("frame pairs need t1 > t0")
        self.v_of = data.u_of / dt_f[:, None, None]
        self._w_vol = np.sqrt(data.c_of / (self.N * self.K))
        # the nodes whose velocities are weighted in some frame (the rest have no residual)
        self._weighted_nodes = np.flatnonzero(np.any(np.asarray(data.c_of) != 0, axis=(0, 2)))
        # the model is driven at the frame times (and t = 0), with the measured force
        # interpolated there; indenter velocities are compared over the same intervals
        t = np.unique(np.concatenate([[0.0], data.t0, data.t1]))
        if t[0] < 0 or t[-1] > data.t_ind[-1] + 1e-9 or t[0] < data.t_ind[0] - 1e-9:
            raise ValueError("frame times must lie within the indenter record")
        self.t_drive = t
        self.noise = noise
        if noise is None:
            self.control = "force"
            self.f_drive = np.interp(t, data.t_ind, data.force)
            self.f_drive[0] = 0.0  # the test starts unloaded (sensor offset removed)
            self.d_drive = np.interp(t, data.t_ind, data.depth)
            self.ddot_exp = np.diff(self.d_drive) / np.diff(t)
            self.M = len(self.ddot_exp)
            self.failed_phi = 1e3   # m^2/s^2, far above any velocity misfit
        else:
            if min(noise.force_N, noise.depth_m, noise.tracking_m) <= 0:
                raise ValueError(f"noise levels must be positive: {noise}")
            self.control = "displacement"
            # the kinks of the load history (reversals, the ends of a hold) are driving times
            # too, and neither the smoothing of the depth nor the interpolation of the model's
            # force crosses them; a kink within one indenter sample of a frame time is taken
            # there (the kink's time is known to about a sample, and a step that short only
            # costs a solve)
            breaks = kinks(data.t_ind, data.depth, noise.depth_m)
            dt_ind = float(np.median(np.diff(data.t_ind)))
            near = np.abs(breaks[:, None] - t[None, :])
            breaks = np.where(near.min(axis=1) <= dt_ind, t[near.argmin(axis=1)], breaks) if t.size else breaks
            self.breaks = np.unique(breaks[(breaks > t[0]) & (breaks < t[-1])])
            t = self.t_drive = np.unique(np.concatenate([t, self.breaks]))
            self.d_drive = smooth_record(data.t_ind, data.depth, noise.depth_m, self.breaks)(t)
            self.d_drive[0] = 0.0
            self.f_drive = self.d_drive
            s = (data.t_ind >= 0) & (data.t_ind <= t[-1] + 1e-12)
            self.t_force, self.f_exp = data.t_ind[s], data.force[s]
            self._force_at_samples = piecewise_quadratic(t, self.t_force, self.breaks)
            self.M = len(self.t_force)
            self._w_vol = self._likelihood_weights(noise)
            # each residual ~ N(0, 1) at the truth: a failed solve costs 1e3 per residual
            self.failed_phi = 1e3 * (self.v_of.size + self.M)
        self.d_meas = np.interp(t, data.t_ind, data.depth)
        self.n_residuals = self.v_of.size + self.M
        # the intuitive axial figure: accumulated tracked motion at confident nodes
        self._U_of = np.cumsum(data.u_of[..., 2], axis=0)
        self._confident = data.c_of[..., 2] >= confidence_floor

    def every(self, m: int) -> "Objective":
        """The same objective on the frame pairs merged `m` at a time (`Measurements.every`),
        with the tracking noise level times sqrt(m): a search on a long record at the cost of
        a short one (about 1/m per solve). Shares the forward model and the observation."""
        if m == 1:
            return self
        noise = None if self.noise is None else replace(
            self.noise, tracking_m=self.noise.tracking_m * np.sqrt(m),
            sources={**self.noise.sources, "frames": f"frame pairs merged {m} at a time"})
        return self._on(self.data.every(m), noise)

    def _on(self, data: Measurements, noise) -> "Objective":
        """This objective's law, forward model, options and observation on other `data` and `noise`."""
        return Objective(self.forward, self.law, data, self.fixed, self.options, self.confidence_floor,
                         self.outside_tol, self.observation, noise)

    def with_measurements(self, data: Measurements) -> "Objective":
        """The same objective on other tracked motion (e.g. less the tracker's error), at the same
        frame times and with the same indenter record, which drives the model: it shares the
        forward model, the observation and the solves it remembers (`solution`)."""
        same = all(np.array_equal(getattr(data, k), getattr(self.data, k)) for k in ("t0", "t1", "t_ind", "depth", "force"))
        if not same:
            raise ValueError("other measurements must have the same frame times and indenter record")
        new = self._on(data, self.noise)
        new._solved = self._solved
        return new

    def with_noise(self, noise) -> "Objective":
        """The same likelihood objective with other noise levels (e.g. block weights
        adjusted for the residuals' correlation); shares everything else."""
        import copy
        if self.noise is None:
            raise ValueError("with_noise needs the likelihood objective (noise=)")
        new = copy.copy(self)
        new.noise = noise
        new._w_vol = self._likelihood_weights(noise)
        return new

    def _likelihood_weights(self, noise):
        """Field-term weights: r_vol = w (v_OF - v_FEM) = sqrt(c) (u_OF - u_FEM) / sigma_track."""
        dt_f = self.data.t1 - self.data.t0
        return np.sqrt(self.data.c_of) * dt_f[:, None, None] / noise.tracking_m

    def residual_groups(self, block_m=0.012, chunk_s=0.25):
        """A label per residual row for the cluster-robust covariance: volumetric rows by
        cube of side `block_m` around their node (all frames and directions of a cube
        together), indenter rows by `chunk_s` of the record.

        12 mm: on the Table 1 setup with the paper's noise (PE, fine-mesh truth, medium model
        mesh, seed 3 optimum) the field block's inflation grows with the block side, 0.51 at
        3 mm, 1.22 at 6 mm, 3.61 at 12 mm, and is unstable beyond (1.7-2.0 from 40 and 5
        groups): the tracking error is correlated over about a centimetre."""
        X = self.forward.mesh.points if self.data.X is None else np.asarray(self.data.X, float)
        cube = np.floor((X - X.min(0)) / block_m).astype(np.int64)
        _, node_group = np.unique(cube, axis=0, return_inverse=True)
        node_group = node_group.ravel()
        vol = np.broadcast_to(node_group[None, :, None], self.v_of.shape).ravel()
        t = self.t_force if self.noise is not None else self.t_drive[1:]
        ind = vol.max(initial=-1) + 1 + np.floor((t - t[0]) / chunk_s).astype(np.int64)
        return np.concatenate([vol, ind])

    @staticmethod
    def _interpolation(mesh, data, outside_tol):
        """None when the tracked nodes are the model mesh's nodes, else the `Probe` that
        interpolates the model's nodal field at them."""
        P = mesh.points
        N = data.u_of.shape[1]
        if data.X is None:
            if N != len(P):
                raise ValueError(f"tracked motion has {N} nodes, the model mesh {len(P)}, and no node "
                                 "coordinates to interpolate at")
            return None
        X = np.asarray(data.X, float)
        if X.shape != (N, 3):
            raise ValueError(f"tracked node coordinates have shape {X.shape}, expected ({N}, 3)")
        scale = float(np.ptp(P, axis=0).max())
        if X.shape == P.shape and np.allclose(X, P, rtol=0, atol=1e-9 * scale):
            return None
        from ..fem.probe import Probe
        probe = Probe(P, mesh.cells, X)
        # distance outside: barycentric excess times the element's size
        T = P[mesh.cells[probe.element, :4]]
        h = np.linalg.norm(T[:, 1:] - T[:, :1], axis=2).max(1)
        far = probe.outside * h > outside_tol
        if far.any():
            raise ValueError(f"{int(far.sum())} tracked nodes lie outside the model mesh (farthest "
                             f"{float((probe.outside * h).max()):.3g} m > {outside_tol:g} m): is it the "
                             "same specimen geometry?")
        log.info("model mesh: %d nodes; tracked nodes interpolated, %d outside it by at most %.2g m",
                 len(P), int((probe.outside > 0).sum()), float((probe.outside * h).max()))
        return probe

    def at_data_nodes(self, u, nodes=None):
        """Model nodal field (..., n_model, 3) at the tracked nodes (..., N, 3), through the
        observation operator if there is one; at the tracked `nodes` only if given."""
        if nodes is not None and hasattr(self.to_data, "at_nodes"):
            return self.to_data.at_nodes(u, nodes)
        out = u if self.to_data is None else self.to_data(u)
        return out if nodes is None else out[..., nodes, :]

    def model_motion(self, t, u):
        """Frame-pair nodal velocities (K, ..., N, 3) of a model history u(t) (n_t, ..., N, 3)."""
        def weights(tq):       # linear interpolation in time as a (len(tq), len(t)) matrix
            k = np.clip(np.searchsorted(t, tq) - 1, 0, len(t) - 2)
            w = (tq - t[k]) / (t[k + 1] - t[k])
            W = np.zeros((len(tq), len(t)))
            np.add.at(W, (np.arange(len(tq)), k), 1 - w)
            np.add.at(W, (np.arange(len(tq)), k + 1), w)
            return W

        def at(tq):
            return (weights(tq) @ u.reshape(len(t), -1)).reshape((len(tq),) + u.shape[1:])
        d = self.data
        V = (weights(d.t1) - weights(d.t0)) / (d.t1 - d.t0)[:, None]
        return (V @ u.reshape(len(t), -1)).reshape((len(d.t1),) + u.shape[1:]), at

    sensitivities = True   # __call__ can give the residual's derivatives (see `directions`)

    def __call__(self, params: dict, directions=None, eps=None) -> Evaluation:
        """Phi and the residuals at `params`; with `directions` (parameter sets moved by `eps`
        along each direction from `params`), also the residual's derivatives along them from
        the solve's sensitivities (`fem.sensitivity`), `Evaluation.jacobian`."""
        full = {**params, **self.fixed}
        try:
            model = self.forward.model(self.law, full)
            variants = None
            if directions is not None:
                variants = [model.with_params(self.forward.element_params(self.law, {**p, **self.fixed}))
                            for p in directions]
        except ValueError as e:
            return Evaluation(dict(params), False, np.nan, np.nan, np.nan, message=str(e))
        return self.evaluate_model(params, model, variants, eps, remember=full)

    #: solved nodal histories kept (`solution`): the multi-start's and the refits' last points
    REMEMBERED = 4

    @staticmethod
    def _key(full: dict):
        return tuple((k, np.asarray(full[k], float).tobytes()) for k in sorted(full))

    def solution(self, params: dict) -> np.ndarray | None:
        """The nodal displacement history (n_drive, 3 n_nodes) of this law's solve at `params`
        (merged with the fixed ones) if it is among the last `REMEMBERED` made by `__call__`,
        else None: the guide of solves of models near it (`solve_history`'s `guide`), e.g.
        the diagnosis's at a fit's optimum."""
        return self._solved.get(self._key({**params, **self.fixed}))

    def evaluate_model(self, params: dict, model, variants=None, eps=None, options=None, guide=None,
                       remember=None) -> Evaluation:
        """Phi and the residuals of a built forward `model` (any parameter set, e.g. an
        extended law at its null values), with the residual's derivatives along the
        `variants` (the same model with parameters moved by `eps`) when given; `options`: Newton
        options other than the objective's own (e.g. a looser tolerance); `guide`: a nearby
        solution's nodal history (`solution`), where the solves start from; `remember`: the
        full parameters of this law that `model` is, to keep its history by (`solution`)."""
        t_start = _time.perf_counter()
        d = self.data
        try:
            sens = Sensitivity(variants, eps) if variants is not None else None
            h = solve_history(model, self.t_drive, self.f_drive, self.control, options or self.options,
                              sensitivity=sens, guide=guide)
        except (ConvergenceError, FloatingPointError, ValueError) as e:
            return Evaluation(dict(params), False, np.nan, np.nan, np.nan,
                              wall_s=_time.perf_counter() - t_start, message=str(e))
        if remember is not None:
            self._solved.pop(key := self._key(remember), None)
            self._solved[key] = h.u.reshape(len(h.u), -1)
            while len(self._solved) > self.REMEMBERED:
                self._solved.pop(next(iter(self._solved)))
        v_fem, at = self.model_motion(self.t_drive, self.at_data_nodes(h.u))
        r_vol = (self._w_vol * (self.v_of - v_fem)).ravel()
        r_ind = self._indenter_residual(h.depth, h.force)
        phi_vol, phi_ind = float(r_vol @ r_vol), float(r_ind @ r_ind)
        rms_force = np.nan if self.noise is None else float(np.sqrt(np.mean(r_ind ** 2))) * self.noise.force_N
        # intuitive figures: displacement errors (accumulated tracked motion for the field)
        rms_depth = float(np.sqrt(np.mean((self.d_meas - h.depth) ** 2)))
        U_fem = at(d.t1)[..., 2] - at(d.t0[:1])[..., 2]
        conf = self._confident
        rms_axial = float(np.sqrt(np.mean((self._U_of - U_fem)[conf] ** 2))) if conf.any() else np.nan
        jac = None
        if sens is not None:
            jac = np.empty((self.n_residuals, sens.k))
            nodes = self._weighted_nodes          # the other nodes' rows are 0
            dv = self.model_motion(self.t_drive, self.at_data_nodes(h.du, nodes))[0]      # (K, k, n_w, 3)
            jv = np.zeros(self.v_of.shape + (sens.k,))
            jv[:, nodes] = -self._w_vol[:, nodes, :, None] * dv.transpose(0, 2, 3, 1)
            jac[: r_vol.size] = jv.reshape(r_vol.size, sens.k)
            for i in range(sens.k):
                jac[r_vol.size:, i] = self._indenter_residual(h.ddepth[:, i], h.dforce[:, i], derivative=True)
        return Evaluation(dict(params), True, phi_vol + phi_ind, phi_vol, phi_ind, rms_depth, rms_axial,
                          rms_force, _time.perf_counter() - t_start, "", np.concatenate([r_vol, r_ind]), v_fem,
                          int(h.iterations.sum()), jac, np.asarray(self.t_drive, float),
                          np.asarray(h.depth, float), np.asarray(h.force, float))

    def _indenter_residual(self, depth, force, derivative=False):
        """The indenter block of the residual for a model depth and force at the driving
        times (or its derivative, from their derivatives): the paper's velocity misfit under
        force control, the noise-weighted force misfit at the samples under depth control."""
        sign = -1.0
        if self.noise is None:
            ddot = np.diff(depth) / np.diff(self.t_drive)
            return (sign * ddot if derivative else self.ddot_exp - ddot) / np.sqrt(self.M)
        f = self._force_at_samples @ force
        return (sign * f if derivative else self.f_exp - f) / self.noise.force_N
