"""Parameter identification: bounded Nelder-Mead (the seed paper's downhill simplex) and
bounded least squares, in normalized parameters, with every forward solve recorded and a
checkpoint that makes an interrupted fit resume with the same result.

Normalization: x = log10(p) for moduli, compliances, times and permeability; x = p for
relaxation fractions (bounded in [0, 0.999]). Bounds are the law's parameter bounds.

Least squares takes its Jacobian from the forward solve's parameter sensitivities
(`fem.sensitivity`; one solve per evaluation) or from forward differences.

Checkpoint: a folder with `evaluations.jsonl` (one line per forward solve),
`residual_<n>.npy` and, for solves with sensitivities, `jacobian_<n>.npy`. A resumed fit replays the deterministic optimizer from the same start;
solves already in the checkpoint are read back instead of recomputed, so the path and the
result are those of an uninterrupted run. `binding.json` records what the solves depend on
(hashes of the data and meshes, the law, the objective's options); a resume with anything
different is refused (`CheckpointMismatch`). A torn last line (a kill while writing) is dropped
and that solve done again. `shared` folders are the checkpoints of fits of the same inputs from
other starts: their solves of this stage are read back too (never written), which spares a
multi-start fit the design stage another start has already solved.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from scipy import optimize

from ..laws import PARAMS, get_law
from .objective import Objective

__all__ = ["Fit", "FAILED_PHI", "CheckpointMismatch"]

log = logging.getLogger(__name__)

FAILED_PHI = 1e3  # m^2/s^2: penalty of a failed forward solve of the paper's Phi (far above any
                  # real misfit); objectives may set their own `failed_phi`

# Least squares stops once the Gauss-Newton step from an accepted point would lower Phi by less
# than this (`Fit.converged_by_gauss_newton`). The likelihood's Phi is in noise variances: 0.01
# leaves every parameter within a tenth of its standard deviation of the optimum. The paper's
# Phi (m^2/s^2) has no such scale: a fraction of Phi instead.
STOP_PHI_LIKELIHOOD = 0.01
STOP_PHI_RELATIVE = 1e-7


class CheckpointMismatch(ValueError):
    """A checkpoint written for other data, meshes, law or options."""


class Fit:
    """Identify the free parameters `names` of `objective.law` from `start`.

    `binding` (JSON-able dict: hashes of the inputs, the law, the options) is written into a
    new checkpoint and must match an existing one."""

    def __init__(self, objective: Objective, start: dict, names=None, checkpoint=None,
                 progress=None, tag="", binding=None, shared=()):
        self.obj = objective
        law = get_law(objective.law)
        self.names = list(names or [n for n in law.free if n not in objective.fixed])
        missing = [n for n in self.names if n not in start]
        if missing:
            raise ValueError(f"start values missing for {missing}")
        self.start = {n: float(start[n]) for n in self.names}
        law.resolve({**self.start, **{k: v for k, v in objective.fixed.items() if k in law.free}})
        self.log_scale = np.array([PARAMS[n].scale == "log" for n in self.names])
        lo = np.array([PARAMS[n].lower for n in self.names], float)
        hi = np.array([PARAMS[n].upper for n in self.names], float)
        at_zero = [n for n, ls in zip(self.names, self.log_scale) if ls and self.start[n] <= 0]
        if at_zero:
            raise ValueError(f"start {', '.join(f'{n}={self.start[n]:g}' for n in at_zero)}: a log-scaled "
                             "parameter needs a start above 0 (to hold it at 0, fix it: --fixed NAME=0)")
        lo = np.where(self.log_scale & (lo <= 0), np.maximum(1e-12, 1e-6 * np.array(list(self.start.values()))), lo)
        self.lo, self.hi = self.to_x(lo), self.to_x(hi)
        self.history: list[dict] = []   # one record per distinct forward solve of this fit
        self.n_calls = 0                 # objective calls of the optimizers (repeats included)
        self._used = set()
        self.progress = progress
        self.ckpt = Path(checkpoint) if checkpoint else None
        self.tag = str(tag)        # stage of a fit sharing the checkpoint (e.g. "balanced")
        self._cache = {}
        self._n_records = 0
        self.sens_step = 1e-6      # normalized step of the sensitivity directions
        self._sensitive = bool(getattr(objective, "sensitivities", False))
        self.failed_phi = float(getattr(objective, "failed_phi", FAILED_PHI))
        if self.ckpt:
            self.ckpt.mkdir(parents=True, exist_ok=True)
            self._bind(binding)
            self._load_checkpoint()
        for folder in shared:
            self._load_shared(Path(folder), binding)

    def _bind(self, binding):
        if binding is None:
            return
        f = self.ckpt / "binding.json"
        binding = json.loads(json.dumps(binding))
        if f.exists():
            try:
                old = json.loads(f.read_text())
            except json.JSONDecodeError:
                old = None
            if old != binding:
                old = old or {}
                diff = sorted(k for k in set(old) | set(binding) if old.get(k) != binding.get(k))
                raise CheckpointMismatch(
                    f"checkpoint {self.ckpt} was written for other inputs (differs in: {', '.join(diff)}); "
                    "use another --checkpoint folder, or --fresh-checkpoint to set this one aside")
            return
        if (self.ckpt / "evaluations.jsonl").exists():
            raise CheckpointMismatch(f"checkpoint {self.ckpt} records no inputs (written by an older liverinv): "
                                     "use another --checkpoint folder, or --fresh-checkpoint")
        tmp = f.with_suffix(".part")
        tmp.write_text(json.dumps(binding, indent=1, sort_keys=True))
        tmp.replace(f)

    def follow(self, other: "Fit"):
        """Number this fit's next solves after those `other` (a stage sharing the checkpoint,
        run since this fit was made) wrote, so that no record or residual file is overwritten."""
        self._n_records = max(self._n_records, other._n_records)

    # -- parameter maps ------------------------------------------------------------------
    def to_x(self, p):
        p = np.asarray(p, float)
        return np.where(self.log_scale, np.log10(np.where(self.log_scale, p, 1.0)), p)

    def to_p(self, x):
        x = np.asarray(x, float)
        return np.where(self.log_scale, 10.0 ** x, x)

    def params_of(self, x) -> dict:
        return dict(zip(self.names, map(float, self.to_p(x))))

    def at_bound(self, x, tol=1e-3) -> np.ndarray:
        """Which parameters of `x` lie within `tol` (in x: log10 or fraction) of a bound."""
        x = np.asarray(x, float)
        return (np.abs(x - self.lo) < tol) | (np.abs(x - self.hi) < tol)

    # -- evaluations -----------------------------------------------------------------------
    @staticmethod
    def _key(x):
        return tuple(float(v).hex() for v in np.asarray(x, float))

    def _near_key(self, x, tol=1e-12):
        """The key of x, or of a recorded solve within `tol` (normalized units) of it: an
        optimizer replayed with another BLAS thread count can land 1 ulp away from the point it
        solved before (measured: a resumed Table 1 fit re-solved 2 of 12 points for that)."""
        key = self._key(x)
        if key in self._cache:
            return key
        for k, rec in self._cache.items():
            if np.max(np.abs(np.asarray(rec["x"]) - x)) <= tol:
                return k
        return key

    def _load_checkpoint(self):
        f = self.ckpt / "evaluations.jsonl"
        if not f.exists():
            return
        lines = f.read_text().splitlines(keepends=True)
        records = []
        for i, line in enumerate(lines):
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:
                if i < len(lines) - 1:
                    raise CheckpointMismatch(f"{f}: line {i + 1} of {len(lines)} is not a record: the "
                                             "checkpoint is damaged; use --fresh-checkpoint") from None
                log.warning("%s: the last line is torn (a kill while writing); dropped, that solve is redone", f)
                tmp = f.with_suffix(".part")
                tmp.write_text("".join(lines[:-1]))
                tmp.replace(f)
        for rec in records:
            self._n_records = max(self._n_records, rec["n"] + 1)
        n = self._cache_records(self.ckpt, records)
        log.info("checkpoint %s: %d solves to replay", self.ckpt, n)

    def _cache_records(self, folder, records, shared=False) -> int:
        """Put this stage's records (tag) of a checkpoint folder, with their residuals and
        Jacobians, in the replay cache; a key already there is kept. Returns how many were added."""
        n = 0
        for rec in records:
            key = tuple(rec["key"])
            if rec.get("tag", "") != self.tag or key in self._cache:   # another stage's solve
                continue
            res = folder / f"residual_{rec['n']}.npy"
            rec["residual"] = np.load(res) if res.exists() else None
            jac = folder / f"jacobian_{rec['n']}.npy"
            rec["jacobian"] = np.load(jac) if jac.exists() else None
            if shared:
                rec["shared_from"] = str(folder)
            self._cache[key] = rec
            n += 1
        return n

    def _load_shared(self, folder: Path, binding):
        """Solves of another fit of the same inputs from another start (its checkpoint folder),
        read back instead of solved again: a multi-start fit's design points and their polish do
        not depend on the start. Only a folder bound to the same inputs is read (else a warning);
        it is never written."""
        if not folder.is_dir():
            log.warning("shared checkpoint %s: no such folder; nothing read", folder)
            return
        try:
            theirs = json.loads((folder / "binding.json").read_text())
        except (OSError, ValueError):
            theirs = None
        if binding is None or theirs != json.loads(json.dumps(binding)):
            log.warning("shared checkpoint %s: not written for the same inputs; its solves are not used", folder)
            return
        log_file = folder / "evaluations.jsonl"
        records = []
        for line in log_file.read_text().splitlines() if log_file.exists() else []:
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:      # a torn last line: that solve is simply not shared
                break
        n = self._cache_records(folder, records, shared=True)
        log.info("shared checkpoint %s: %d solves to read back", folder, n)

    def evaluate(self, x, purpose="step", jacobian=False) -> dict:
        """One forward solve at normalized x (or its replay from the checkpoint); with
        `jacobian`, also the residual's derivatives by x from the solve's sensitivities
        (`rec["jacobian"]`, None where the objective cannot give them)."""
        x = np.clip(np.asarray(x, float), self.lo, self.hi)
        key = self._near_key(x)
        self.n_calls += 1
        want = jacobian and self._sensitive
        cached = self._cache.get(key)
        stale = cached is not None and want and cached["ok"] and cached.get("jacobian") is None
        if key in self._used and not stale:   # asked again (e.g. a Jacobian at the accepted point)
            return cached
        if cached is not None and not stale:
            rec = dict(cached)
            rec["replayed"] = True
        else:
            steps = None
            if want:
                ev, steps = self.solve_with_jacobian(x)
            else:
                ev = self.obj(self.params_of(x))
            n = self._n_records
            self._n_records += 1
            rec = dict(key=list(key), x=list(map(float, x)), params=ev.params, ok=ev.ok,
                       phi=ev.phi if ev.ok else self.failed_phi, phi_vol=ev.phi_vol, phi_ind=ev.phi_ind,
                       rms_depth=ev.rms_depth, rms_axial=ev.rms_axial,
                       rms_force=getattr(ev, "rms_force", np.nan), wall_s=ev.wall_s,
                       message=ev.message, purpose=purpose, n=n, replayed=False, tag=self.tag)
            rec["residual"] = ev.residual
            J = getattr(ev, "jacobian", None)
            rec["jacobian"] = None if J is None else J * np.sign(steps)   # columns along +x
            if self.ckpt:
                if ev.residual is not None:
                    np.save(self.ckpt / f"residual_{n}.npy", ev.residual)
                if rec["jacobian"] is not None:
                    np.save(self.ckpt / f"jacobian_{n}.npy", rec["jacobian"])
                with open(self.ckpt / "evaluations.jsonl", "a") as f:
                    f.write(json.dumps({k: v for k, v in rec.items()
                                        if k not in ("residual", "jacobian", "replayed")}) + "\n")
            self._cache[key] = rec
        self._used.add(key)
        self.history.append(rec)
        if self.progress:
            self.progress(rec)
        return rec

    def solve_with_jacobian(self, x):
        """One forward solve at normalized x with the sensitivities along every normalized
        parameter (stepping backward at an upper bound): (Evaluation, steps)."""
        x = np.asarray(x, float)
        steps = np.where(x + self.sens_step <= self.hi, self.sens_step, -self.sens_step)
        directions = [self.params_of(x + h * e) for h, e in zip(steps, np.eye(len(x)))]
        return self.obj(self.params_of(x), directions=directions, eps=self.sens_step), steps

    def residual(self, x, purpose="step"):
        """Residual vector at normalized x (a failed solve: the uniform penalty vector)."""
        rec = self.evaluate(x, purpose)
        if rec["ok"] and rec["residual"] is not None:
            return rec["residual"]
        return np.full(self.obj.n_residuals, np.sqrt(self.failed_phi / self.obj.n_residuals))

    def fd_jacobian(self, x, fd_step=1e-3, purpose="step", fd_purpose="fd-jacobian"):
        """Forward-difference Jacobian of the residual vector at normalized x (one recorded
        solve per parameter; steps backward at an upper bound). Returns (J, r(x))."""
        x = np.asarray(x, float)
        r0 = self.residual(x, purpose)
        J = np.empty((len(r0), len(x)))
        for i in range(len(x)):
            h = fd_step if x[i] + fd_step <= self.hi[i] else -fd_step
            e = x.copy()
            e[i] += h
            J[:, i] = (self.residual(e, fd_purpose) - r0) / h
        return J, r0

    # -- optimizers -----------------------------------------------------------------------
    def nelder_mead(self, max_evaluations=400, xatol=1e-3, fatol=1e-4, initial_step=0.1):
        """Bounded downhill simplex (scipy, Gao-Han adaptive off) in normalized parameters;
        the initial simplex steps `initial_step` (decades for log parameters)."""
        x0 = self.to_x(list(self.start.values()))
        sim = [x0]
        for i in range(len(x0)):
            e = x0.copy()
            e[i] += initial_step if x0[i] + initial_step <= self.hi[i] else -initial_step
            sim.append(e)

        def f(x):
            rec = self.evaluate(x, "nelder-mead")
            return rec["phi"]

        res = optimize.minimize(f, x0, method="Nelder-Mead", bounds=list(zip(self.lo, self.hi)),
                                options=dict(maxfev=max_evaluations, xatol=xatol, fatol=0.0,
                                             initial_simplex=np.array(sim)))
        return self._result(res.x, "nelder-mead", res.message)

    def least_squares(self, max_evaluations=200, fd_step=1e-3, trust_radius=0.3, x0=None,
                      jacobian="sensitivity"):
        """Bounded trust-region least squares (scipy "dogbox": a box-shaped trust region
        intersected with the bounds) on the residual vector, from the start or from
        normalized x0.

        The optimizer works in z = (x - x0) / trust_radius, so its first trust region is
        `trust_radius` normalized units (decades for log parameters) in every direction
        around the start. (scipy's default first radius is |x0|, about ten decades here, and
        its "trf" method rescales steps by the distance to the bounds: from Table 1 seed 1
        the first step jumped to C2 1489, kappa 5e-10, far from where the linear model
        holds.)

        Jacobian: ``"sensitivity"`` (default) from the forward solve itself (direct
        differentiation along the normalized parameters, `fem.sensitivity`): every
        evaluation of the optimizer is one solve that also gives its Jacobian. ``"fd"``, and
        wherever the objective gives no sensitivities: forward differences at each accepted
        point, one more recorded solve per parameter ("fd-jacobian").
        `max_evaluations` bounds scipy's residual evaluations."""
        if jacobian not in ("sensitivity", "fd"):
            raise ValueError(f"jacobian must be 'sensitivity' or 'fd', not {jacobian!r}")
        sens = jacobian == "sensitivity"
        x0 = self.to_x(list(self.start.values())) if x0 is None else np.clip(np.asarray(x0, float), self.lo, self.hi)
        s = float(trust_radius)
        lo, hi = (self.lo - x0) / s, (self.hi - x0) / s

        def residual(z):
            x = x0 + s * z
            rec = self.evaluate(x, "least-squares", jacobian=sens)
            return rec["residual"] if rec["ok"] and rec["residual"] is not None else self.residual(x)

        # scipy's gtol is absolute: the residual is scaled to unit norm at the start, since Phi is
        # about 1e-9 (m^2/s^2) in the paper's objective and 1e3 in the likelihood (unscaled, the
        # paper's fits stopped on the gradient while still 7 % off on an analytic problem)
        r0 = float(np.linalg.norm(residual(np.zeros_like(x0))))
        c = 1.0 / r0 if np.isfinite(r0) and r0 > 0 else 1.0

        def fun(z):
            return c * residual(z)

        def jac(z):
            x = x0 + s * z
            rec = self.evaluate(x, "least-squares", jacobian=sens)
            if rec.get("jacobian") is not None:
                return c * s * rec["jacobian"]
            return c * s * self.fd_jacobian(x, fd_step, "least-squares", "fd-jacobian")[0]

        def stop_when_converged(z):
            if self.converged_by_gauss_newton(x0 + s * z):
                raise StopIteration

        res = optimize.least_squares(fun, np.zeros_like(x0), jac=jac, bounds=(lo, hi), method="dogbox",
                                     max_nfev=max_evaluations, xtol=1e-8, ftol=1e-10, gtol=1e-10,
                                     callback=stop_when_converged)
        message = res.message if res.status != -2 else (
            f"converged: the Gauss-Newton step would lower Phi by less than {self.stop_phi(res.cost / c**2 * 2):.3g}")
        out = self._result(x0 + s * res.x, "least-squares", message)
        out["jacobian"] = res.jac / (c * s)
        out["x_end"] = x0 + s * res.x
        return out

    def stop_phi(self, phi: float) -> float:
        """Decrease of Phi below which least squares has converged: `STOP_PHI_LIKELIHOOD` for
        the noise-aware objective (Phi in noise variances), else `STOP_PHI_RELATIVE` x Phi."""
        return STOP_PHI_LIKELIHOOD if getattr(self.obj, "noise", None) is not None else STOP_PHI_RELATIVE * phi

    def converged_by_gauss_newton(self, x) -> bool:
        """Whether the Gauss-Newton step from the solved point x would lower Phi by less than
        `stop_phi`: the squared norm of the residual's projection on the Jacobian's range, with
        the parameters held at a bound that the gradient pushes against left out. (scipy's own
        tests, on the step length and the relative change of the cost, went on for 2-4 solves that
        changed Phi by less than 1e-4 after the noise-aware fits had converged.)"""
        rec = self._cache.get(self._near_key(np.clip(np.asarray(x, float), self.lo, self.hi)))
        if rec is None or not rec["ok"] or rec.get("jacobian") is None or rec.get("residual") is None:
            return False
        J, r = np.asarray(rec["jacobian"]), np.asarray(rec["residual"])
        g = J.T @ r                                  # half the gradient of Phi along +x
        x = np.asarray(rec["x"])
        span = self.hi - self.lo
        held = ((x <= self.lo + 1e-9 * span) & (g > 0)) | ((x >= self.hi - 1e-9 * span) & (g < 0))
        free = ~held
        if not free.any():
            return True
        step, *_ = np.linalg.lstsq(J[:, free], -r, rcond=None)
        predicted = float(np.sum((J[:, free] @ step) ** 2))
        return predicted < self.stop_phi(float(rec["phi"]))

    def design(self, n_points, seed=0):
        """`n_points` normalized points of a scrambled Sobol sequence (fixed seed) over the
        parameters' search ranges (`Param.search`, clipped to the bounds). The design does not
        depend on the start, so fits from different starts screen the same points."""
        from scipy.stats import qmc

        lo, hi = np.array([PARAMS[n].search for n in self.names], float).T
        lo, hi = np.maximum(self.to_x(lo), self.lo), np.minimum(self.to_x(hi), self.hi)
        u = qmc.Sobol(len(self.names), scramble=True, seed=seed).random(n_points)
        return lo + u * (hi - lo)

    def multistart(self, n_design=16, n_polish=2, max_evaluations=200, probe_evaluations=10, fd_step=1e-3,
                   trust_radius=0.3, seed=0, jacobian="sensitivity"):
        """A global stage for laws with several minima (e.g. a relaxation time below the frame
        interval or a nearly incompressible valley, where the gradient vanishes):

        1. least squares from the start, at most `probe_evaluations` residual evaluations;
        2. Phi at the `n_design` points of `design` (one solve each), and least squares from
           the `n_polish` best of them, at most `probe_evaluations` each;
        3. least squares to convergence (`max_evaluations`) from the lowest Phi of those runs.

        Every solve is recorded in the history; the fit's result is the lowest Phi of all."""
        probe = min(probe_evaluations, max_evaluations)
        runs = [self.least_squares(probe, fd_step, trust_radius, jacobian=jacobian)]
        pts = self.design(n_design, seed)
        phis = np.array([self.evaluate(x, "design")["phi"] for x in pts])
        for k in np.argsort(phis, kind="stable")[:n_polish]:
            runs.append(self.least_squares(probe, fd_step, trust_radius, x0=pts[k], jacobian=jacobian))
        best_run = min(runs, key=lambda r: self.evaluate(r["x_end"], "least-squares")["phi"])
        final = self.least_squares(max_evaluations, fd_step, trust_radius, x0=best_run["x_end"], jacobian=jacobian)
        out = self._result(final["x_end"], "least-squares multistart",
                           f"least squares from the start and {n_polish} of {n_design} design points "
                           f"({probe} residual evaluations each), continued from the best: {final['message']}")
        out["jacobian"] = final["jacobian"]
        out["runs"] = [dict(x_end=r["x_end"], message=r["message"]) for r in runs + [final]]
        return out

    def _result(self, x, method, message):
        best = min((r for r in self.history if r["ok"]), key=lambda r: r["phi"], default=None)
        return dict(method=method, message=str(message), x=np.asarray(x), params=self.params_of(x),
                    best=best, n_solves=len(self.history),
                    n_replayed=sum(1 for r in self.history if r.get("replayed")),
                    n_shared=sum(1 for r in self.history if r.get("shared_from")), n_calls=self.n_calls)
