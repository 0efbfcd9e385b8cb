r"""Parameter sensitivities of a load history by direct differentiation.

At every converged backward-Euler step n the model satisfies R(q_n, sigma_{n-1}, theta) = f_n
(sigma the history state before the step: J_n of the biphasic model, the Prony integrals
and last stresses of QLV) and commits sigma_n = commit(sigma_{n-1}, q_n, theta). Differentiating
along a parameter direction theta_i::

    K_n s_n = -(dR/dtheta_i + dR/dsigma . dsigma_{n-1})            s_n = dq_n / dtheta_i
    dsigma_n = dcommit/dsigma . dsigma_{n-1} + dcommit/dq . s_n + dcommit/dtheta_i

with K_n the tangent at the converged state (force control: the punch row is the force,
which is prescribed, so its right-hand side is the same; displacement control: the punch
depth is prescribed, its sensitivity is zero). The right-hand side and the state update are
*directional finite differences of the model's own residual and commit*, with the parameter,
the history and the solution stepped together by eps along the direction: one residual
evaluation each, and no derivative code per law. The tangent system is solved with

* ``"exact"`` (default): the tangent factorized at the converged state of every step (exact
  to the finite-difference step), one block back-substitution for all directions; the
  factorization then also serves the next step's quasi-Newton iterations;
* ``"secant"``: the solver's current factorization with its limited-memory BFGS pairs, the
  same approximate inverse the quasi-Newton iterations used, followed by `refine`
  iterations of ``s += B^-1 (rhs - K s)`` with K s a directional difference of the residual.
  Cheaper per step but inexact where the factorization is old: on the coarse benchmark
  mesh (PE, 40 frames) 1-5 % error with 2 corrections, 9-35 % without, at the cost of
  "exact" with 2 corrections.

Cost per step: "exact" one tangent assembly and numeric factorization, two residual
evaluations per direction and one block back-substitution; on the coarse benchmark mesh a
PE solve with four directions takes about 2.4x a plain solve.

A parameter direction is given as a copy of the model with its parameters moved by eps
along it (`with_params`), so the same code serves any parametrization (e.g. the
identification's log10 parameters).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Sensitivity"]


def _state_arrays(state):
    return {k: v for k, v in vars(state).items() if isinstance(v, np.ndarray)}


def state_axpy(a, b, beta):
    """The history state a + beta b (field by field; b may be None: a itself)."""
    if b is None or beta == 0.0:
        return a
    new = a.__class__.__new__(a.__class__)
    new.__dict__.update(vars(a))
    for k, v in _state_arrays(a).items():
        setattr(new, k, v + beta * getattr(b, k))
    return new


def state_difference(a, b, scale):
    """(a - b) * scale, field by field."""
    new = a.__class__.__new__(a.__class__)
    new.__dict__.update(vars(a))
    for k, v in _state_arrays(a).items():
        setattr(new, k, (v - getattr(b, k)) * scale)
    return new


class Sensitivity:
    """Direct-differentiation sensitivities along parameter directions (see module doc).

    Parameters
    ----------
    variants : models with the parameters moved by `eps` along each direction (same mesh
        and boundary conditions as the solved model, e.g. `Biphasic.with_params`)
    eps : the step of the variants along their directions
    solve : "exact" (factorize the tangent at every converged step) or "secant" (reuse the
        solver's factorization and BFGS pairs, with `refine` corrections)
    refine : correction iterations of the "secant" solve
    """

    def __init__(self, variants, eps: float, solve: str = "exact", refine: int = 2):
        if solve not in ("secant", "exact"):
            raise ValueError(f"solve must be 'secant' or 'exact', not {solve!r}")
        self.variants, self.eps, self.solve, self.refine = list(variants), float(eps), solve, int(refine)
        self.k = len(self.variants)
        self.S = None          # (n_red, k) current dq/dtheta
        self.dstate = None     # history-state derivatives, one per direction

    def start(self, model, state):
        self.S = np.zeros((model.n_red, self.k))
        self.dstate = [None] * self.k

    def step(self, eng, q, ev, dt, state, new_state, control):
        # (models may define state_after(state, q, dt), the committed history without a
        # residual evaluation; otherwise evaluate + commit)
        """Advance the sensitivities over one converged step (q, ev at its end; `state`
        before it, `new_state` after)."""
        from .solver import _lbfgs

        model, eps = eng.model, self.eps
        p = model.punch_index
        if self.solve == "exact":
            eng.refactor(q, dt, state, control)
            eng.pairs, eng.fresh = [], False
            pairs = []
        else:
            if not eng.has_factor:
                eng.refactor(q, dt, state, control)
                eng.pairs, eng.fresh = [], False
            pairs = eng.pairs
        inv = lambda b: _lbfgs(b, pairs, eng.solve)
        states = [state_axpy(state, self.dstate[i], eps) for i in range(self.k)]
        rhs = np.column_stack([-(var.evaluate(q, dt, st_i, tangent=False).r - ev.r) / eps
                               for var, st_i in zip(self.variants, states)])
        if control == "displacement":
            rhs[p] = 0.0
        if self.solve == "exact":
            self.S = eng.solve(rhs)                      # one block back-substitution
        else:
            for i in range(self.k):
                s = inv(rhs[:, i])
                for _ in range(self.refine):
                    res = rhs[:, i] - (model.evaluate(q + eps * s, dt, state, tangent=False).r - ev.r) / eps
                    if control == "displacement":
                        res[p] = 0.0
                    s = s + inv(res)
                self.S[:, i] = s
        for i, (var, st_i) in enumerate(zip(self.variants, states)):
            q_i = q + eps * self.S[:, i]
            if hasattr(var, "state_after"):
                after = var.state_after(st_i, q_i, dt)
            else:
                after = var.commit(st_i, var.evaluate(q_i, dt, st_i, tangent=False), dt)
            self.dstate[i] = state_difference(after, new_state, 1.0 / eps)
