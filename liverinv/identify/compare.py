"""Is one law's fit clearly worse than another's on the same data? A paired test of their misfits.

Two laws fitted to the same data leave residuals r_A and r_B on the same rows. Much of each
misfit is the data's own error (tracking error above all), common to both; what tells the
laws apart is the difference of their squared residuals, row by row,
``d_i = r_A,i^2 - r_B,i^2 = (m_A,i - m_B,i)(m_A,i + m_B,i + 2 e_i)`` (m the model errors, e
the data error), which the common error enters only through the models' difference. The
test sums d over the residual's clusters (`Objective.residual_groups`: 12 mm cubes of tracked
nodes with all their frames, 0.25 s of the indenter record), since tracking errors are
correlated in space and time, and compares the total with its cluster-robust standard error::

    Delta = sum_g d_g,    se = sqrt(G / (G - 1) sum_g (d_g - mean d)^2),    z = Delta / se

(Vuong's test for non-nested models, with clustered rows). z > 2.33 (one-sided p < 0.01)
says A is worse than B by more than the data's own error explains. For nested laws (SR in
SBR) a z near the boundary is only indicative: the larger law always fits at least as well.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

__all__ = ["group_misfit", "paired_misfit_test", "WORSE_Z"]

WORSE_Z = float(stats.norm.isf(0.01))     # one-sided 1 % level: 2.326


def group_misfit(residual, groups, n_groups: int | None = None, scale=None) -> np.ndarray:
    """Sum of squared residuals per cluster label (0 .. n_groups - 1); `scale` multiplies each
    row's square (e.g. to bring a fit's noise levels to common ones)."""
    r2 = np.asarray(residual, float) ** 2
    if scale is not None:
        r2 = r2 * scale
    return np.bincount(np.asarray(groups, np.intp), r2, minlength=n_groups or 0)


def paired_misfit_test(phi_a, phi_b) -> dict:
    """The paired test of A against B from their misfits per cluster (`group_misfit`, the same
    clusters): the difference of the totals `delta`, its standard error `se`, `z` and the
    one-sided p-value that A is worse than B (`p_worse`)."""
    d = np.asarray(phi_a, float) - np.asarray(phi_b, float)
    if d.shape != np.shape(phi_b) or d.ndim != 1:
        raise ValueError("the two misfits must be given per cluster, on the same clusters")
    G = d.size
    delta = float(d.sum())
    se = float(np.sqrt(G / (G - 1) * np.sum((d - d.mean()) ** 2))) if G > 1 else np.nan
    z = delta / se if se > 0 else (np.inf * np.sign(delta) if delta else 0.0)
    return dict(delta=delta, se=se, z=float(z), p_worse=float(stats.norm.sf(z)), n_groups=G)
