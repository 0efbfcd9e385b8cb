r"""Darcy flow at the drained limit, to first order: the direction of the poroelastic effect
on a solid model, without solving the biphasic model.

The biphasic weak form (`biphasic`, kappa the spatial permeability) is, at t_{n+1}::

    R_u = int (F S_solid - p J F^-T) : Grad du dV - f_ext . du = 0
    R_p = int dp (J - J_n) dV + dt int kappa J (C^-1 Grad p) . Grad dp dV = 0

For a large permeability write p = theta pi with theta = 1/kappa. To first order in theta the
skeleton's motion is the drained (solid) solution's, so pi follows from its volume change
alone, one Poisson problem per step on the P1 pressure nodes (pi = 0 on the draining faces,
no flux elsewhere)::

    dt int J (C^-1 Grad pi) . Grad dp dV = -int dp (J - J_n) dV

and the pore pressure adds the force ``-theta int pi J F^-T : Grad du dV`` to R_u. So
dR_u/dtheta at the drained null is ``-g`` with ``g = int pi J F^-T : Grad du dV``: a force on
the solid model's unknowns, which `sensitivity.Sensitivity` takes as a direction
(`force`). The motion's change u -> u + theta s then changes J and pi at order theta^2 only.
(Tested against the biphasic model's own sensitivity at a large permeability:
tests/test_darcy.py.)
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .biphasic import DRAINED_DEFAULT, pressure_shape
from .material import _det

__all__ = ["DrainedDarcy"]


class DrainedDarcy:
    """The first-order Darcy flow direction of a solid model (see module doc): `force` gives,
    step after step of a converged history, ``-dR/da`` for the amplitude a of
    ``1/kappa = scale * a`` (`scale` in N s/m^4, the amplitude's unit)."""

    def __init__(self, space, drained=DRAINED_DEFAULT, scale=1.0):
        mesh = space.mesh
        self.space, self.scale = space, float(scale)
        self.Np, self.dNpdX = pressure_shape(space)
        p_nodes = mesh.corner_nodes()
        corner_id = -np.ones(mesh.n_nodes, dtype=np.int64)
        corner_id[p_nodes] = np.arange(len(p_nodes))
        self.p_elem = corner_id[space.conn[:, :4]]                    # (ne, 4)
        dry = np.zeros(mesh.n_nodes, dtype=bool)
        for g in drained:
            dry[mesh.nodes(g)] = True
        self.free = np.flatnonzero(~dry[p_nodes])
        self.n_p = len(p_nodes)
        rows = np.repeat(self.p_elem, 4, axis=1).ravel()
        cols = np.tile(self.p_elem, (1, 4)).ravel()
        self._rc = rows, cols
        self.start()

    def start(self):
        self._J_prev = np.ones(self.space.dV.shape)

    def pressure(self, F, dt):
        """pi (ne, nq) at the quadrature points and J, for a step of length dt ending at F."""
        J = _det(F)
        Ci = np.linalg.inv(np.swapaxes(F, -1, -2) @ F)
        w = J * self.space.dV                                          # (ne, nq)
        CiG = self.dNpdX @ Ci                                          # (ne, nq, 4, 3), C^-1 symmetric
        Le = np.einsum("eq,eqbi,eqci->ebc", w, CiG, self.dNpdX, optimize=True)
        L = sp.csr_matrix((Le.ravel(), self._rc), shape=(self.n_p, self.n_p))
        b = np.zeros(self.n_p)
        np.add.at(b, self.p_elem, ((J - self._J_prev) * self.space.dV) @ self.Np)
        pi = np.zeros(self.n_p)
        f = self.free
        if dt > 0 and len(f):
            pi[f] = sla.spsolve(L[f][:, f].tocsc(), -b[f] / dt)
        return pi[self.p_elem] @ self.Np.T, J

    def force(self, model, q, dt) -> np.ndarray:
        """-dR/dtheta of `model` (a solid model on this space) at its converged q of the next
        step, in its reduced unknowns; advances to that step."""
        F = self.space.deformation_gradient(model.displacement(q))
        pi, J = self.pressure(F, dt)
        Finv_T = np.swapaxes(np.linalg.inv(F), -1, -2)
        g = model.asm.vector(self.space.internal_force((self.scale * pi * J)[..., None, None] * Finv_T))
        self._J_prev = J
        return g
