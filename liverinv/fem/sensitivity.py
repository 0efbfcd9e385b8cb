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
evaluation each, and no derivative code per law. The tangent is factorized at the converged
state of every step (exact to the finite-difference step) and one block back-substitution
serves all directions; the factorization then also serves the next step's quasi-Newton
iterations. (Reusing the solver's older factorization with its BFGS pairs instead, plus two
correction iterations, was 1-35 % off on the coarse benchmark mesh at the same cost.)

Cost per step: one tangent assembly and numeric factorization, one residual evaluation per
direction (two for a model without `state_after`; for a direction that changes the parameters
of a few elements of an elastic model, e.g. an inclusion's sphere, the residual change on those
elements only: `Indentation.residual_change`) and one block back-substitution. On the Table 1
data a PE solve with four directions takes 2.34x a plain solve on the coarse and on the
medium mesh (`benchmarks/sensitivity_cost.py`: 16.8 vs 7.2 s, 51.4 vs 21.9 s).

A parameter direction is given as a copy of the model with its parameters moved by eps
along it (`with_params`), so the same code serves any parametrization (e.g. the
identification's log10 parameters). A direction may instead be a term the model lacks, given
by its force: an object with ``start()`` and ``force(model, q, dt)``, -dR/dtheta of the term
at the null at each converged step (e.g. `darcy.DrainedDarcy`); the model's own history then
carries its effect on later steps.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Sensitivity"]


def _state_arrays(state):
    return {k: v for k, v in vars(state).items() if isinstance(v, np.ndarray)}


def _state_map(a, b, f):
    """A history state whose array fields are f(a.field, b.field)."""
    new = a.__class__.__new__(a.__class__)
    new.__dict__.update(vars(a))
    for k, v in _state_arrays(a).items():
        setattr(new, k, f(v, getattr(b, k)))
    return new


def state_axpy(a, b, beta):
    """The history state a + beta b (field by field; b may be None: a itself)."""
    return a if b is None or beta == 0.0 else _state_map(a, b, lambda x, y: x + beta * y)


def state_difference(a, b, scale):
    """(a - b) * scale, field by field."""
    return _state_map(a, b, lambda x, y: (x - y) * scale)


def _is_force(direction) -> bool:
    return hasattr(direction, "force") and not hasattr(direction, "evaluate")


class Sensitivity:
    """Direct-differentiation sensitivities along parameter directions (see module doc).

    Parameters
    ----------
    variants : models with the parameters moved by `eps` along each direction (same mesh
        and boundary conditions as the solved model, e.g. `Biphasic.with_params`)
    eps : the step of the variants along their directions
    linearized : use the model's batched, linearized step where it has one
        (`Indentation.linearized_directions`, `fem.linearized`); False: the generic
        finite differences of `evaluate` and `state_after` for every model
    """

    def __init__(self, variants, eps: float, linearized: bool = True):
        self.variants, self.eps = list(variants), float(eps)
        self.k = len(self.variants)
        self.linearized = linearized
        self.batch = None      # the model's LinearizedDirections, if used
        self.S = None          # (n_red, k) current dq/dtheta
        self.dstate = None     # history-state derivatives, one per direction
        self.dforce = None     # (k,) derivative of the punch force (displacement control)

    def start(self, model, state):
        self.S = np.zeros((model.n_red, self.k))
        self.dstate = [None] * self.k
        self.dforce = np.zeros(self.k)
        for var in self.variants:
            if _is_force(var):
                var.start()
        make = getattr(model, "linearized_directions", None) if self.linearized else None
        self.batch = make(self.variants, self.eps, _is_force) if make is not None else None
        if self.batch is not None:
            self.batch.start()

    def step(self, eng, q, ev, dt, state, new_state, control):
        """Advance the sensitivities over one converged step (q, ev at its end; `state`
        before it, `new_state` after). Models may define ``state_after(state, q, dt)``, the
        committed history without a residual evaluation; otherwise evaluate + commit."""
        eps = self.eps
        p = eng.model.punch_index
        tangent = eng.evaluate(q, dt, state, True)   # the tangent at the converged state
        # displacement control: the punch force r_p is a result; its row of the tangent
        # (before the punch is fixed) gives dF = dr_p/dtheta + K_p . s
        K_p = tangent.K[[p]].toarray().ravel() if control == "displacement" else None
        eng.refactor(q, dt, state, control, tangent)  # (it also serves the next step's iterations)
        eng.pairs, eng.fresh = [], False
        if self.batch is not None:
            rhs = self.batch.rhs(q, dt, state, ev)
            for i, var in enumerate(self.variants):
                if _is_force(var):
                    rhs[:, i] += var.force(eng.model, q, dt)
            self._solve(eng, rhs, control, K_p)
            self.batch.commit(q, dt, state, self.S)
            return
        states = [state_axpy(state, self.dstate[i], eps) for i in range(self.k)]
        change = getattr(eng.model, "residual_change", None)   # cheap for element-local changes
        rhs = np.empty((len(ev.r), self.k))
        for i, (var, st_i) in enumerate(zip(self.variants, states)):
            if _is_force(var):    # an added term: its force, and the history's change
                rhs[:, i] = var.force(eng.model, q, dt)
                if self.dstate[i] is not None:
                    rhs[:, i] -= (eng.model.evaluate(q, dt, st_i, tangent=False).r - ev.r) / eps
                continue
            d = change(var, q) if change is not None else None
            rhs[:, i] = -(d if d is not None else var.evaluate(q, dt, st_i, tangent=False).r - ev.r) / eps
        self._solve(eng, rhs, control, K_p)
        for i, (var, st_i) in enumerate(zip(self.variants, states)):
            var = eng.model if _is_force(var) else var
            q_i = q + eps * self.S[:, i]
            if hasattr(var, "state_after"):
                after = var.state_after(st_i, q_i, dt)
            else:
                after = var.commit(st_i, var.evaluate(q_i, dt, st_i, tangent=False), dt)
            # an elastic model keeps its (empty) history: nothing to differentiate
            self.dstate[i] = None if after is new_state else state_difference(after, new_state, 1.0 / eps)

    def _solve(self, eng, rhs, control, K_p):
        """S from the right-hand sides (one block back-substitution); under displacement
        control the punch row is the force's derivative instead."""
        p = eng.model.punch_index
        if control == "displacement":
            dr_p = -rhs[p].copy()
            rhs[p] = 0.0
        self.S = eng.solve(rhs)
        if control == "displacement":
            self.dforce = dr_p + K_p @ self.S
