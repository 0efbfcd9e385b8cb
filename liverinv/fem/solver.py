"""Quasi-static load stepping: quasi-Newton (BFGS on a reused factorization) or full
Newton-Raphson, with line search and automatic step cutting.

`solve_history` drives an `Indentation` model through a prescribed history of the punch
depth (displacement control) or the punch force (force control, the depth is the result),
recording the converged state at every requested time.

Strategy ("bfgs", the default): the tangent is assembled and factorized only when needed;
between refreshes each iteration costs one residual evaluation and one back-substitution,
with the limited-memory BFGS update (two-loop recursion) on top of the factorized tangent,
as in FEBio's default solver. The tangent is refreshed when the residual contracts by less
than `refresh_ratio` per iteration or a step needs more than `refresh_after` iterations.
"full": a new tangent at every iteration (quadratic convergence, more factorizations).
"""

from __future__ import annotations

import logging
import time as _time
from dataclasses import dataclass, field

import numpy as np

from .indentation import Indentation
from .linsolve import SparseSolver

__all__ = ["NewtonOptions", "History", "solve_history", "ConvergenceError"]

log = logging.getLogger(__name__)


class ConvergenceError(RuntimeError):
    """The load step could not be completed even after the allowed step cuts."""


class _StepFailure(Exception):
    pass


@dataclass
class NewtonOptions:
    method: str = "bfgs"      # "bfgs" (reuse factorization) or "full" (Newton-Raphson)
    rtol: float = 1e-6        # residual norm relative to the force scale
    f_floor: float = 1e-3     # N, force scale floor (near zero load)
    max_iter: int = 30
    max_cuts: int = 8         # a step may be split 2**max_cuts times
    refresh_ratio: float = 0.3
    refresh_after: int = 6
    bfgs_memory: int = 10
    keep_pairs: bool = True   # carry BFGS pairs across steps until the next refactorization
    extrapolate: bool = True  # predictor: extrapolate the last converged solutions in time
    solver: str | None = None  # "pardiso" or "superlu" (default: pardiso when installed)
    keep_factorization: bool = False  # History.linear_solver keeps the last factorization


@dataclass
class History:
    time: np.ndarray
    depth: np.ndarray
    force: np.ndarray
    u: np.ndarray                 # (n_frames, n_nodes, 3)
    iterations: np.ndarray        # nonlinear iterations per frame (all sub-steps)
    cuts: np.ndarray              # number of step cuts per frame
    timing: dict = field(default_factory=dict)
    state: object = None          # last QLV state
    q: np.ndarray | None = None   # last reduced solution
    linear_solver: object = None  # SparseSolver with the last factorized tangent (if kept)
    du: np.ndarray | None = None      # (n_frames, k, n_nodes, 3) sensitivities of u, if asked
    ddepth: np.ndarray | None = None  # (n_frames, k) sensitivities of the punch depth
    dforce: np.ndarray | None = None  # (n_frames, k) sensitivities of the punch force


class _Engine:
    """Evaluations, the current factorization and the cost counters of one run."""

    def __init__(self, model, opts):
        self.model, self.opts = model, opts
        self.lin = SparseSolver(opts.solver, symmetric=getattr(model, "symmetric_tangent", False))
        self.fresh = False      # factorization taken at the current iterate
        self.has_factor = False
        self.pairs = []         # BFGS secant pairs on top of the current factorization
        self.t_assembly = self.t_factor = self.t_solve = self.t_sensitivity = 0.0
        self.n_residual = self.n_tangent = self.n_solve = 0

    def evaluate(self, q, dt, state, tangent):
        t0 = _time.perf_counter()
        ev = self.model.evaluate(q, dt, state, tangent=tangent)
        self.t_assembly += _time.perf_counter() - t0
        if tangent:
            self.n_tangent += 1
        else:
            self.n_residual += 1
        return ev

    def refactor(self, q, dt, state, control, ev=None):
        """Factorize the tangent at q (reusing `ev` when it already holds that tangent)."""
        if ev is None or ev.K is None:
            ev = self.evaluate(q, dt, state, True)
        K = self.model.fix_punch(ev.K) if control == "displacement" else ev.K
        t0 = _time.perf_counter()
        self.lin.factorize(K)
        self.t_factor += _time.perf_counter() - t0
        self.has_factor = True
        return ev

    def solve(self, b):
        t0 = _time.perf_counter()
        x = self.lin.solve(b)
        self.t_solve += _time.perf_counter() - t0
        self.n_solve += 1
        return x


def _residual(model, ev, control, target):
    r = ev.r.copy()
    if control == "displacement":
        r[model.punch_index] = 0.0
    else:
        r[model.punch_index] -= target
    return r


def _admissible(ev):
    return np.isfinite(ev.r).all() and ev.J_min > 0


def _lbfgs(r, pairs, solve):
    """Two-loop recursion: approximate K^-1 r with the stored (s, y, rho) pairs."""
    v = r.copy()
    alphas = []
    for s, y, rho in reversed(pairs):
        a = rho * (s @ v)
        v -= a * y
        alphas.append(a)
    z = solve(v)
    for (s, y, rho), a in zip(pairs, reversed(alphas)):
        b = rho * (y @ z)
        z += (a - b) * s
    return z


def _tangent_predictor(eng, q0, target, dt, state):
    """Linearized response to moving the punch from q0[p] to `target` with the tangent at
    q0 (moving only the footprint nodes can invert the rim elements in a large step)."""
    model = eng.model
    p = model.punch_index
    ev = eng.evaluate(q0, dt, state, True)
    dd = target - q0[p]
    rhs = -np.asarray(ev.K[:, [p]].todense()).ravel() * dd
    t0 = _time.perf_counter()
    eng.lin.factorize(model.fix_punch(ev.K))
    eng.t_factor += _time.perf_counter() - t0
    eng.has_factor, eng.fresh, eng.pairs = True, False, []
    rhs[p] = dd
    return q0 + eng.solve(rhs)


def _step(eng, q, dt, state, control, target, predict=False):
    """Equilibrium at the end of one step from the initial guess q (with `predict`, under
    displacement control, from the tangent predictor at q instead)."""
    model, opts = eng.model, eng.opts
    p = model.punch_index
    q0 = q.copy()
    q = q.copy()
    if control == "displacement":
        q[p] = target
    predict = predict and control == "displacement"
    ev = None if predict else eng.evaluate(q, dt, state, False)
    if predict or (control == "displacement" and not _admissible(ev)):
        q = _tangent_predictor(eng, q0, target, dt, state)
        ev = eng.evaluate(q, dt, state, False)
    if not _admissible(ev):
        raise _StepFailure("initial guess inverts an element")
    r = _residual(model, ev, control, target)
    pairs = eng.pairs if opts.keep_pairs else []
    refresh = opts.method == "full" or not eng.has_factor
    rnorm = np.linalg.norm(r)
    for it in range(opts.max_iter + 1):
        scale = max(abs(ev.r[p]), abs(target) if control == "force" else 0.0, opts.f_floor)
        if rnorm <= opts.rtol * scale:
            return q, ev, it
        if it == opts.max_iter:
            break
        if it >= opts.refresh_after and not eng.fresh:
            refresh = True
        if refresh:
            ev = eng.refactor(q, dt, state, control, ev)
            eng.fresh, refresh, pairs = True, False, []
            eng.pairs = pairs
        dq = -_lbfgs(r, pairs, eng.solve)
        if not np.isfinite(dq).all():
            raise _StepFailure("linear solve failed")
        alpha, accepted = 1.0, False
        for _ in range(6):
            q_try = q + alpha * dq
            # full Newton needs the tangent at the accepted point: compute it with the
            # residual of the full step instead of evaluating that point twice
            ev_try = eng.evaluate(q_try, dt, state, opts.method == "full" and alpha == 1.0)
            if _admissible(ev_try):
                r_try = _residual(model, ev_try, control, target)
                n_try = np.linalg.norm(r_try)
                if n_try < (1 - 1e-4 * alpha) * rnorm:
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            if not eng.fresh:  # a stale tangent led astray: refresh and try again
                refresh = True
                continue
            raise _StepFailure(f"line search failed at iteration {it} (|r| = {rnorm:.3e})")
        eng.fresh = False
        s, y = q_try - q, r_try - r
        sy = s @ y
        if opts.method == "bfgs" and sy > 1e-14 * np.linalg.norm(s) * np.linalg.norm(y):
            pairs.append((s, y, 1.0 / sy))
            del pairs[:-opts.bfgs_memory]
        if n_try > opts.refresh_ratio * rnorm or opts.method == "full":
            refresh = True
        q, ev, r, rnorm = q_try, ev_try, r_try, n_try
    raise _StepFailure(f"no convergence in {opts.max_iter} iterations (|r| = {rnorm:.3e})")


def _extrapolate(past, t):
    """Lagrange extrapolation in time of the last two or three converged solutions."""
    ts = [p[0] for p in past]
    guess = np.zeros_like(past[-1][1])
    for j, (tj, qj) in enumerate(past):
        w = 1.0
        for m, tm in enumerate(ts):
            if m != j:
                w *= (t - tm) / (tj - tm)
        guess += w * qj
    return guess


def _guided(model, guide, k, past, past_frame, t):
    """The guess at frame k from the `guide`: its solution there plus the difference from it
    extrapolated in time over the last converged frames (held, from one frame)."""
    diff = [(tj, qj - model.asm.reduce(guide[j])) for (tj, qj), j in zip(past, past_frame) if j is not None]
    ahead = model.asm.reduce(guide[k])
    return ahead + (_extrapolate(diff, t) if len(diff) >= 2 else diff[-1][1])


def solve_history(model: Indentation, times, values, control="displacement",
                  options: NewtonOptions | None = None, record=None, sensitivity=None, guide=None) -> History:
    """Run the model through a load history.

    Parameters
    ----------
    model : Indentation
    times : (n,) strictly increasing times in s; times[0] is the undeformed start
    values : (n,) punch depth in m (displacement control) or force in N (force control);
        values[0] must be 0
    control : "displacement" or "force"
    options : NewtonOptions
    record : optional callable(frame, q, evaluation) called at every frame after the first
    sensitivity : optional `sensitivity.Sensitivity`: the derivatives of u and of the punch
        depth along its parameter directions at every frame (History.du, History.ddepth)
    guide : optional (n, 3 n_nodes) nodal displacements (row-major) of a nearby solution at
        `times`, e.g. the fitted law's own history when this model is that law with a
        term added: each step starts from the guide at its end plus the extrapolated
        difference of this solution from it (`_guided`), before the other guesses. On the
        diagnosis of the warped elastic null of seed 44 (31 frames) the secant solves then
        took 0.56-0.88 of their time unguided, and the fitted law itself, solved again with
        a spring on the bottom, 0.60-0.64 (2.1 iterations a step against 4.4).

    A model whose equilibrium depends on time beyond the punch (e.g. the registration
    springs of `liverinv.identify.register`) may define `set_time(t)`: it is called with the
    end time of every step and sub-step before that step is solved.
    """
    if control not in ("displacement", "force"):
        raise ValueError(f"control must be 'displacement' or 'force', not {control!r}")
    opts = options or NewtonOptions()
    if opts.method not in ("bfgs", "full"):
        raise ValueError(f"method must be 'bfgs' or 'full', not {opts.method!r}")
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    if times.ndim != 1 or len(times) != len(values) or len(times) < 2:
        raise ValueError("times and values must be 1-D arrays of the same length >= 2")
    if np.any(np.diff(times) <= 0):
        raise ValueError("times must increase strictly")
    if values[0] != 0:
        raise ValueError("the history must start from zero load (values[0] = 0)")
    n = len(times)
    if guide is not None:
        guide = np.asarray(guide, float)
        if guide.ndim != 2 or guide.shape[0] != n or guide.shape[1] > model.asm.index.size:
            raise ValueError(f"the guide must hold one displacement vector per time ({n}), not shape {guide.shape}")
    eng = _Engine(model, opts)
    t_start = _time.perf_counter()
    state = model.new_state()
    q = np.zeros(model.n_red)
    past = [(times[0], q)]  # last converged (time, solution) pairs for the predictor
    past_frame = [0]        # ... and the frame each is at (None: a sub-step of a cut step)
    u = np.zeros((n, model.space.mesh.n_nodes, 3))
    depth, force = np.zeros(n), np.zeros(n)
    iters, cuts = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    p = model.punch_index
    set_time = getattr(model, "set_time", None)
    if sensitivity is not None:
        sensitivity.start(model, state)
        du = np.zeros((n, sensitivity.k, model.space.mesh.n_nodes, 3))
        ddepth = np.zeros((n, sensitivity.k))
        dforce = np.zeros((n, sensitivity.k))
    for k in range(1, n):
        pending = [(times[k - 1], values[k - 1], times[k], values[k], 0)]
        while pending:
            ta, va, tb, vb, level = pending.pop()
            dt = tb - ta
            if set_time is not None:
                set_time(tb)
            # no extrapolation yet (the first step, or its cuts): the punch alone would move,
            # so start from the tangent's response instead (not from the guide's guess)
            guesses = [(q, len(past) < 2)]
            if opts.extrapolate and len(past) >= 2:
                guesses.insert(0, (_extrapolate(past, tb), False))
            if guide is not None and level == 0:
                guesses.insert(0, (_guided(model, guide, k, past, past_frame, tb), False))
            err = None
            for guess, predict in guesses:
                try:
                    q_new, ev, it = _step(eng, guess, dt, state, control, vb, predict=predict)
                    err = None
                    break
                except _StepFailure as e:
                    err = e
                    eng.pairs, eng.has_factor = [], False  # secant data of a failed try is unsafe
            if err is not None:
                if level >= opts.max_cuts:
                    raise ConvergenceError(f"step to t = {tb:.6g} s failed after {level} cuts: {err}")
                log.info("cutting step [%g, %g] s: %s", ta, tb, err)
                tm, vm = 0.5 * (ta + tb), 0.5 * (va + vb)
                pending += [(tm, vm, tb, vb, level + 1), (ta, va, tm, vm, level + 1)]
                cuts[k] += 1
                continue
            iters[k] += it
            new_state = model.commit(state, ev, dt)
            if sensitivity is not None:
                t_s = _time.perf_counter()
                sensitivity.step(eng, q_new, ev, dt, state, new_state, control)
                eng.t_sensitivity += _time.perf_counter() - t_s
            state = new_state
            q = q_new
            past = (past + [(tb, q)])[-3:]
            past_frame = (past_frame + [k if tb == times[k] else None])[-3:]
            last = ev
        u[k] = model.displacement(q)
        depth[k], force[k] = q[p], last.r[p]
        if sensitivity is not None:
            n_u = 3 * model.space.mesh.n_nodes    # (a biphasic model's pressures follow)
            du[k] = model.asm.expand(sensitivity.S)[:n_u].T.reshape(sensitivity.k, -1, 3)
            ddepth[k] = sensitivity.S[p]
            dforce[k] = sensitivity.dforce if control == "displacement" else 0.0
        if record is not None:
            record(k, q, last)
    timing = dict(wall_s=_time.perf_counter() - t_start, assembly_s=eng.t_assembly,
                  factor_s=eng.t_factor, solve_s=eng.t_solve, residuals=eng.n_residual,
                  tangents=eng.n_tangent, factorizations=eng.lin.n_factorizations,
                  back_substitutions=eng.n_solve, solver=eng.lin.method,
                  sensitivity_s=eng.t_sensitivity)
    kept = None
    if opts.keep_factorization:
        eng.refactor(q, times[-1] - times[-2], state, control)  # the tangent at the end state
        kept = eng.lin
    else:
        eng.lin.free()
    h = History(times, depth, force, u, iters, cuts, timing, state, q, kept)
    if sensitivity is not None:
        h.du, h.ddepth, h.dforce = du, ddepth, dforce
    return h
