"""Gauss-Newton uncertainty at the optimum, and what the indenter data alone can tell.

With the Jacobian J of the residual vector in normalized parameters x (log10 for log-scaled
parameters), cov_x = s^2 (J^T J)^-1 with s^2 = |r|^2 / (m - n), m the number of rows that
carry data (zero-confidence rows of the field term are all-zero and do not count). A
log-scaled parameter's relative standard deviation is ln(10) sd_x. Repeating this with only
the indenter rows of J (and their own residual scale) shows which parameters the
force/displacement record alone cannot determine.

Tracking errors are correlated in space (neighbouring nodes share image windows) and in time
(on the Table 1-like informative case the frame-pair error of a node correlates 0.97 with
the next pair's), so the independent-residual covariance above is far too small. With
`groups` (a label per residual row: blocks of nodes over all frames, chunks of the indenter
record) `gauss_newton` reports the cluster-robust (sandwich) covariance instead,

    cov = A^-1 (G/(G-1) sum_g J_g^T r_g r_g^T J_g) A^-1,    A = J^T J,

which holds for any correlation within a group and any scale of the noise.
"""

from __future__ import annotations

import numpy as np

__all__ = ["gauss_newton", "cluster_robust", "block_inflation"]


def _cov(J, s2):
    JtJ = J.T @ J
    try:
        cond = float(np.linalg.cond(JtJ))
        cov = s2 * np.linalg.pinv(JtJ, rcond=1e-14)
    except np.linalg.LinAlgError:
        return np.full((J.shape[1], J.shape[1]), np.nan), np.inf
    return cov, cond


def _group_scores(J, r, groups):
    """J_g^T r_g of every group of rows that carries data, (G, n)."""
    live = np.any(J != 0, axis=1) | (r != 0)
    _, inverse = np.unique(np.asarray(groups)[live], return_inverse=True)
    U = np.zeros((inverse.max(initial=-1) + 1, J.shape[1]))
    np.add.at(U, inverse, J[live] * r[live, None])
    return U


def cluster_robust(J, r, groups):
    """Sandwich covariance of least-squares parameters with residuals correlated within
    `groups` (one label per row), and the number of groups that carry data."""
    JtJ = J.T @ J
    U = _group_scores(J, r, groups)
    G = len(U)
    B = U.T @ U * (G / max(G - 1, 1))
    try:
        Ainv = np.linalg.pinv(JtJ, rcond=1e-14)
    except np.linalg.LinAlgError:
        return np.full_like(JtJ, np.nan), G
    return Ainv @ B @ Ainv, G


def block_inflation(J, r, groups, rows) -> float:
    """How much more a block of residual `rows` varies than its weights claim: the mean
    eigenvalue of (J_b^T J_b)^-1 B_b, B_b the cluster-robust meat of the block (1 for
    independent residuals of unit variance; the residual variance times the design effect of
    its correlation otherwise). Dividing the block's residuals by its square root makes its
    information honest against the other blocks (a composite-likelihood adjustment)."""
    J_b, r_b = J[rows], r[rows]
    U = _group_scores(J_b, r_b, np.asarray(groups)[rows])
    if len(U) == 0:
        return 1.0
    A = J_b.T @ J_b
    sv = np.linalg.svd(A, compute_uv=False)
    rank = int(np.sum(sv > sv[0] * 1e-10)) if sv.size and sv[0] > 0 else 0
    if rank == 0:
        return 1.0
    return float(np.trace(np.linalg.pinv(A, rcond=1e-10) @ (U.T @ U)) / rank)


def gauss_newton(J, r, n_ind, log_scale, groups=None):
    """Covariance, correlation, condition number and relative standard deviations of the
    parameters, from all residuals and from the last `n_ind` (indenter) residuals only;
    with `groups`, the cluster-robust covariance (module doc)."""
    n = J.shape[1]
    live = np.any(J != 0, axis=1) | (r != 0)
    s2 = float(r @ r) / max(int(live.sum()) - n, 1)
    cov, cond = _cov(J, s2)
    n_groups = 0
    if groups is not None:
        cov, n_groups = cluster_robust(J, r, groups)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    corr = cov / np.outer(sd, sd) if np.all(sd > 0) else np.full_like(cov, np.nan)
    J_ind, r_ind = J[-n_ind:], r[-n_ind:]
    cov_ind, cond_ind = _cov(J_ind, float(r_ind @ r_ind) / max(n_ind - n, 1))
    sd_ind = np.sqrt(np.clip(np.diag(cov_ind), 0, None))
    rel = np.where(log_scale, np.log(10.0) * sd, sd)
    rel_ind = np.where(log_scale, np.log(10.0) * sd_ind, sd_ind)
    # a parameter is determined by a data set when its relative sd is below 10 %
    # (fractions: absolute sd below 0.1); the indenter rows alone are rank-deficient in D1
    # when force data cannot separate bulk from shear response
    sv = np.linalg.svd(J_ind, compute_uv=False)
    rank_ind = int(np.sum(sv > sv[0] * 1e-6)) if sv.size else 0
    return dict(cov_x=cov, corr=corr, cond=cond, rel_sd=rel, rel_sd_indenter_only=rel_ind, n_groups=n_groups,
                cond_indenter_only=cond_ind, rank_indenter_only=rank_ind,
                determined=rel < 0.1, determined_by_indenter=rel_ind < 0.1)
