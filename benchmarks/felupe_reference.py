"""Peer-code reference for the canonical indentation benchmark, computed with felupe.

The benchmark (``/work/shared/benchmark/README.md``): a tissue cylinder, bottom fixed, a
frictionless rigid flat punch of radius ``a`` pressed ``depth`` into the top face under
displacement control, reduced polynomial law in the Abaqus convention

    U = C1 (Ī1 - 3) + C2 (Ī1 - 3)^2 + (1/D1) (J - 1)^2,   Ī1 = J^(-2/3) tr C,

so that mu0 = 2 C1 and K0 = 2 / D1. felupe assembles and solves; the law's stress and
tangent are written here in closed form (no tensortrax needed) and checked against finite
differences by ``tests/test_felupe_reference.py``.

Usage::

    python benchmarks/felupe_reference.py --mesh cylinder_coarse.msh \
        --law-params C1=200,C2=5000,D1=1.5e-3 --steps 46

Examples
--------
>>> out = run_felupe("cylinder_coarse.msh", 200.0, 5000.0, 1.5e-3)  # doctest: +SKIP
>>> round(out["force_4p6mm"], 4), round(out["force_9p2mm"], 4)  # doctest: +SKIP
(0.1985, 0.846)
"""

from __future__ import annotations

import argparse
import logging
import os
import time
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

__all__ = ["reduced_polynomial_umat", "run_felupe", "QUADRATURES"]

#: Quadrature name -> order of felupe's TetrahedronQuadrature (4, 5 and 14 points).
QUADRATURES = {"tet10-4pt": 2, "tet10-5pt": 3, "tet10-14pt": 5}

#: Benchmark geometry (m).
H_DEFAULT = 0.0303
A_DEFAULT = 0.006


def _kinematics(F):
    """J, F^-T, I1 and J^(-2/3) of deformation gradients of shape (3, 3, ...)."""
    J = np.linalg.det(np.moveaxis(F, (0, 1), (-2, -1)))
    iF = np.moveaxis(np.linalg.inv(np.moveaxis(F, (0, 1), (-2, -1))), (-2, -1), (0, 1))
    iFT = np.swapaxes(iF, 0, 1)
    I1 = np.einsum("iJ...,iJ...->...", F, F)
    with np.errstate(invalid="ignore"):  # J <= 0 gives NaN, which fails the Newton step
        Jm23 = J ** (-2.0 / 3.0)
    return J, iFT, I1, Jm23


def _stress(x, C1, C2, D1):
    """First Piola-Kirchhoff stress P = dU/dF (felupe ``Material`` signature)."""
    F, statevars = x[0], x[-1]
    J, iFT, I1, Jm23 = _kinematics(F)
    I1b = Jm23 * I1
    W1 = C1 + 2.0 * C2 * (I1b - 3.0)
    dI1b = 2.0 * Jm23 * (F - I1 / 3.0 * iFT)
    P = W1 * dI1b + (2.0 / D1) * (J - 1.0) * J * iFT
    return [P, statevars]


def _elasticity(x, C1, C2, D1):
    """Fourth-order tangent A_iJkL = dP_iJ / dF_kL (felupe ``Material`` signature)."""
    F = x[0]
    J, iFT, I1, Jm23 = _kinematics(F)
    I1b = Jm23 * I1
    W1 = C1 + 2.0 * C2 * (I1b - 3.0)
    G = 2.0 * Jm23 * (F - I1 / 3.0 * iFT)  # dĪ1/dF
    eye = np.eye(3)
    # d(F^-T)_iJ / dF_kL = -iFT_iL iFT_kJ
    dFinvT = -np.einsum("iL...,kJ...->iJkL...", iFT, iFT)
    dG = (
        -2.0 / 3.0 * np.einsum("iJ...,kL...->iJkL...", G, iFT)
        + 2.0 * Jm23 * (
            np.einsum("ik,JL->iJkL", eye, eye)[..., None, None]
            - 2.0 / 3.0 * np.einsum("iJ...,kL...->iJkL...", iFT, F)
            - I1 / 3.0 * dFinvT
        )
    )
    s = (2.0 / D1) * (J - 1.0) * J  # volumetric: P_vol = s(J) F^-T
    ds = (2.0 / D1) * (2.0 * J - 1.0) * J  # J ds/dJ
    A = (
        2.0 * C2 * np.einsum("iJ...,kL...->iJkL...", G, G)
        + W1 * dG
        + ds * np.einsum("iJ...,kL...->iJkL...", iFT, iFT)
        + s * dFinvT
    )
    return [A]


def reduced_polynomial_umat(C1, C2, D1):
    """felupe material for U = C1 (Ī1-3) + C2 (Ī1-3)^2 + (1/D1) (J-1)^2.

    Parameters
    ----------
    C1, C2 : float
        Deviatoric coefficients (Pa); mu0 = 2 C1.
    D1 : float
        Compressibility (1/Pa); K0 = 2 / D1.

    Returns
    -------
    felupe.Material
    """
    import felupe as fem

    return fem.Material(_stress, _elasticity, C1=C1, C2=C2, D1=D1)


def _superlu(A, b):
    """SuperLU with the minimum-degree ordering of A^T + A (2-3x faster than COLAMD here)."""
    from scipy.sparse.linalg import spsolve

    return spsolve(A.tocsc(), b, permc_spec="MMD_AT_PLUS_A")


def _linear_solver(name):
    """Sparse solver callable for felupe: "pardiso" (pypardiso), "superlu" or "auto"."""
    if name not in ("auto", "pardiso", "superlu"):
        raise ValueError(f"solver must be 'auto', 'pardiso' or 'superlu', got {name!r}")
    if name in ("auto", "pardiso"):
        try:
            import pypardiso

            return "pardiso", pypardiso.spsolve
        except ImportError:
            if name == "pardiso":
                raise
    return "superlu", _superlu


def _load_mesh(mesh_path, quadrature):
    """Read a gmsh tet10 mesh with meshio and build felupe's region and field."""
    import felupe as fem
    import meshio

    if quadrature not in QUADRATURES:
        raise ValueError(f"quadrature must be one of {sorted(QUADRATURES)}, got {quadrature!r}")
    m = meshio.read(mesh_path)
    cells = m.get_cells_type("tetra10")  # meshio hands tet10 in VTK order = felupe order
    if len(cells) == 0:
        raise ValueError(f"mesh_path {mesh_path}: no tetra10 cells")
    mesh = fem.Mesh(np.asarray(m.points, dtype=float), np.asarray(cells), "tetra10")
    region = fem.Region(mesh, fem.QuadraticTetra(),
                        fem.TetrahedronQuadrature(order=QUADRATURES[quadrature]))
    field = fem.FieldContainer([fem.Field(region, dim=3)])
    return mesh, field


def run_felupe(mesh_path, C1, C2, D1, depth=9.2e-3, steps=46, unload=True,
               quadrature="tet10-4pt", H=H_DEFAULT, a=A_DEFAULT, tol=None, maxiter=16,
               solver="auto", linesearch=False, max_cuts=0, verbose=False):
    """Solve the displacement-controlled flat-punch benchmark with felupe.

    Parameters
    ----------
    mesh_path : str or Path
        gmsh mesh with ``tetra10`` cells (e.g. ``cylinder_coarse.msh``).
    C1, C2, D1 : float
        Reduced polynomial parameters (Pa, Pa, 1/Pa).
    depth : float
        Maximum punch displacement d (m), default 9.2e-3.
    steps : int
        Equal displacement increments from 0 to ``depth`` (and as many back if ``unload``).
    unload : bool
        Also ramp back to d = 0.
    quadrature : {"tet10-4pt", "tet10-5pt", "tet10-14pt"}
        Tetrahedron quadrature rule.
    H, a : float
        Cylinder height and punch radius (m): footprint nodes are z = H, r <= a + 1e-9.
    tol : float or None
        felupe's Newton tolerance on |f_free| / (1e-3 + |f_prescribed|) (default felupe's
        sqrt(machine eps)).
    maxiter : int
        Newton iterations allowed per step.
    solver : {"auto", "pardiso", "superlu"}
        Sparse direct solver: pypardiso (if installed, "auto" prefers it) or scipy's
        SuperLU. Both give the same numbers; pardiso is several times faster.
    linesearch : bool
        Add felupe's backtracking ``LinesearchPlugin`` to the Newton iterations.
    max_cuts : int
        Halvings of a displacement increment allowed after a failed Newton solve (0: the
        run stops at the first failure, as for the benchmark reference numbers).
    verbose : bool
        Let felupe print its Newton tables.

    Returns
    -------
    dict
        ``depth`` (n+1,) punch displacement d >= 0 (m), starting with 0; ``force`` (n+1,)
        F = -sum of footprint z reactions (N, positive compressive); ``iterations`` (n+1,)
        Newton iterations per converged step (0 for the initial state); ``loading`` (n+1,)
        True on the loading branch; ``min_J`` (n+1,) smallest det F over the quadrature
        points; ``newton_iterations`` total (plus ``maxiter`` for
        each failed attempt); ``step_cuts``; ``wall_time_s``; ``force_4p6mm`` and
        ``force_9p2mm`` (F on loading at d = 4.6e-3 and 9.2e-3 m, NaN if not reached);
        ``n_nodes``, ``n_cells``, ``n_footprint_nodes``, ``params``, ``quadrature``,
        ``solver``, ``completed`` (False if Newton failed; the arrays then stop at the last
        converged step).
    """
    import felupe as fem

    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    if depth <= 0:
        raise ValueError(f"depth must be positive, got {depth}")
    if C1 <= 0 or C2 < 0 or D1 <= 0:
        raise ValueError(f"need C1 > 0, C2 >= 0, D1 > 0, got {C1}, {C2}, {D1}")
    solver_name, solve_linear = _linear_solver(solver)
    t0 = time.perf_counter()
    mesh, field = _load_mesh(mesh_path, quadrature)
    X = mesh.points
    r = np.hypot(X[:, 0], X[:, 1])
    bottom = np.isclose(X[:, 2], 0.0, atol=1e-9)
    footprint = np.isclose(X[:, 2], H, atol=1e-9) & (r <= a + 1e-9)
    if not footprint.any() or not bottom.any():
        raise ValueError(f"mesh_path {mesh_path}: no footprint or bottom nodes for H={H}, a={a}")

    umat = reduced_polynomial_umat(C1, C2, D1)
    solid = fem.SolidBody(umat, field)
    boundaries = {
        "bottom": fem.Boundary(field[0], mask=bottom),
        "punch": fem.Boundary(field[0], mask=footprint, skip=(1, 1, 0)),
    }
    dof0, dof1 = fem.dof.partition(field, boundaries)
    zdofs = 3 * np.flatnonzero(footprint) + 2

    ramp = np.linspace(0.0, depth, steps + 1)[1:]
    path = np.concatenate([ramp, ramp[::-1][1:], [0.0]]) if unload else ramp
    d_out, f_out, it_out, load_out, minj_out = [0.0], [0.0], [0], [True], [1.0]
    n_cuts = n_failed_its = 0
    completed = True
    kw = {} if tol is None else {"tol": tol}
    plugins = [fem.LinesearchPlugin()] if linesearch else None
    d_prev = 0.0
    for k, d_target in enumerate(path):
        pending, cuts_here = [d_target], 0
        while pending:
            d = pending[0]
            u_conv = field[0].values.copy()
            boundaries["punch"].value = -d
            ext0 = fem.dof.apply(field, boundaries, dof0)
            try:
                res = fem.newtonraphson(items=[solid], dof1=dof1, dof0=dof0, ext0=ext0,
                                        maxiter=maxiter, solver=solve_linear, plugins=plugins,
                                        verbose=2 if verbose else 0, **kw)
            except ValueError as exc:  # NewtonConvergenceError subclasses ValueError
                field[0].values = u_conv  # back to the last converged state
                n_failed_its += maxiter
                if cuts_here >= max_cuts:
                    logger.warning("felupe Newton failed at d = %.4g m: %s", d, exc)
                    completed = False
                    break
                cuts_here += 1
                n_cuts += 1
                pending.insert(0, 0.5 * (d_prev + d))
                logger.info("step cut: retrying at d = %.4e m", pending[0])
                continue
            field.link(res.x)  # keep the container the boundaries refer to
            pending.pop(0)
            d_prev = d
            d_out.append(d)
            f_out.append(-float(np.sum(res.fun[zdofs])))
            it_out.append(res.iterations)
            load_out.append(k < steps)
            minj_out.append(float(np.linalg.det(
                np.moveaxis(field.extract()[0], (0, 1), (-2, -1))).min()))
            logger.info("d = %.4e m  F = %.6f N  min J = %.4f  (%d iterations)", d, f_out[-1],
                        minj_out[-1], res.iterations)
        if not completed:
            break
    wall = time.perf_counter() - t0

    depth_arr, force_arr = np.array(d_out), np.array(f_out)
    loading = np.array(load_out)

    def on_loading(target):
        dl, fl = depth_arr[loading], force_arr[loading]
        hit = np.flatnonzero(np.isclose(dl, target, rtol=0, atol=1e-12))
        if hit.size:
            return float(fl[hit[0]])
        return float(np.interp(target, dl, fl)) if dl[-1] >= target else float("nan")

    return {
        "depth": depth_arr,
        "force": force_arr,
        "iterations": np.array(it_out),
        "newton_iterations": int(np.sum(it_out)) + n_failed_its,
        "step_cuts": n_cuts,
        "loading": loading,
        "min_J": np.array(minj_out),
        "wall_time_s": wall,
        "force_4p6mm": on_loading(4.6e-3),
        "force_9p2mm": on_loading(9.2e-3),
        "n_nodes": int(len(X)),
        "n_cells": int(len(mesh.cells)),
        "n_footprint_nodes": int(footprint.sum()),
        "params": {"C1": C1, "C2": C2, "D1": D1},
        "quadrature": quadrature,
        "solver": solver_name,
        "completed": completed,
    }


def _parse_params(text):
    out = {}
    for item in text.split(","):
        key, _, val = item.partition("=")
        if key.strip() not in ("C1", "C2", "D1"):
            raise argparse.ArgumentTypeError(f"unknown law parameter {key!r}")
        out[key.strip()] = float(val)
    missing = {"C1", "C2", "D1"} - set(out)
    if missing:
        raise argparse.ArgumentTypeError(f"missing law parameters {sorted(missing)}")
    return out


def main(argv=None):
    """Command-line entry: run one case and print a one-line table."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mesh", type=Path, required=True)
    p.add_argument("--law-params", type=_parse_params, default="C1=200,C2=5000,D1=1.5e-3")
    p.add_argument("--steps", type=int, default=46)
    p.add_argument("--depth", type=float, default=9.2e-3)
    p.add_argument("--no-unload", action="store_true")
    p.add_argument("--quadrature", choices=sorted(QUADRATURES), default="tet10-4pt")
    p.add_argument("--solver", choices=("auto", "pardiso", "superlu"), default="auto")
    p.add_argument("--linesearch", action="store_true", help="felupe LinesearchPlugin")
    p.add_argument("--max-cuts", type=int, default=0, help="step halvings after a failure")
    p.add_argument("--maxiter", type=int, default=16, help="Newton iterations per step")
    p.add_argument("--curve", type=Path, help="write depth, force, iterations as CSV here")
    p.add_argument("-v", "--verbose", action="store_true")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    os.environ.setdefault("FELUPE_VERBOSE", "false")
    lp = args.law_params
    out = run_felupe(args.mesh, lp["C1"], lp["C2"], lp["D1"], depth=args.depth,
                     steps=args.steps, unload=not args.no_unload, quadrature=args.quadrature,
                     solver=args.solver, linesearch=args.linesearch, max_cuts=args.max_cuts,
                     maxiter=args.maxiter)
    if args.curve:
        args.curve.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.curve.with_name(f".{args.curve.name}.part")
        np.savetxt(tmp, np.column_stack([out["depth"], out["force"], out["iterations"]]),
                   delimiter=",", header="depth_m,force_N,newton_iterations", comments="")
        os.replace(tmp, args.curve)
    print("mesh | C1 | C2 | D1 | quadrature | F(4.6mm) N | F(9.2mm) N | F end N | "
          "newton its | step cuts | wall s | completed")
    print(f"{args.mesh.name} | {lp['C1']:g} | {lp['C2']:g} | {lp['D1']:g} | {args.quadrature}"
          f" | {out['force_4p6mm']:.6f} | {out['force_9p2mm']:.6f} | {out['force'][-1]:.3e}"
          f" | {out['newton_iterations']} | {out['step_cuts']} | {out['wall_time_s']:.1f}"
          f" | {out['completed']}")
    return 0 if out["completed"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
