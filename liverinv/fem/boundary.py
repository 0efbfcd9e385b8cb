"""The indentation test's displacement boundary conditions, one definition for both models
(`indentation.Indentation` and `biphasic.Biphasic`).

The punch footprint's axial displacement is one unknown shared by its nodes, the punch depth
d (u_z = -d: the nodes are *tied*, numbered after the free ones with sign -1). Its tangential
motion is free (frictionless, where a tangential spring of stiffness k_punch may restrain it)
or held (bonded). The bottom face is held (fixed), holds u_z only (sliding), or holds u_z with a
tangential spring of compliance c_bottom (compliant). The side is free, or confined (u_x = u_y =
0, confined compression).

A sliding bottom leaves the body's rigid in-plane motion (two translations, a rotation about the
axis) to be held. Pins do it at no cost only where the symmetric solution does not move them:
u_x = u_y = 0 at a bottom node on the punch axis and u_y = 0 at one on the +x axis. A mesh without
a bottom node on the axis (both benchmark cylinders: the coarse one's nearest lies 2.6 mm off it)
gets instead a tangential spring of compliance C_SLIDING on the bottom, the bottom-slip term's
sliding end: pinning the node nearest the axis there held its radial motion at zero, which
translated the body 0.09 mm and, with the +x pin, turned it 1.9e-3 rad about the axis (0.09 mm at
the rim of the coarse mesh at 6 mm depth: in the motion, not in the force).
"""

from __future__ import annotations

import numpy as np

from .springs import FaceSpring

__all__ = ["C_SLIDING", "PUNCH_CONTACTS", "SUPPORTS", "SIDES", "check_names", "constrained_components",
           "displacement_numbering", "face_springs", "sliding_pins"]

PUNCH_CONTACTS = ("frictionless", "bonded")
SUPPORTS = ("fixed", "sliding", "compliant")
SIDES = ("free", "confined")
C_SLIDING = 1e-2     # m/Pa: the sliding bottom's tangential compliance where pins would move it


def check_names(punch: str, support: str, side: str = "free") -> None:
    """ValueError naming the choices for a punch contact, support or side that is not one."""
    for what, value, choices in (("punch contact", punch, PUNCH_CONTACTS), ("support", support, SUPPORTS),
                                 ("side", side, SIDES)):
        if value not in choices:
            raise ValueError(f"{what} must be one of {choices}, not {value!r}")


def constrained_components(mesh, punch="frictionless", support="fixed", side="free"):
    """(fixed, tied): (n_nodes, 3) boolean masks of the displacement components held at zero
    and of those tied to the punch depth (the footprint's u_z)."""
    check_names(punch, support, side)
    n = mesh.n_nodes
    footprint, bottom = mesh.nodes("footprint"), mesh.nodes("bottom")
    fixed = np.zeros((n, 3), dtype=bool)
    if support == "fixed":
        fixed[bottom] = True
    else:
        fixed[bottom, 2] = True
    pins = sliding_pins(mesh) if support == "sliding" else None
    if pins is not None:
        fixed[pins[0], :2] = True
        fixed[pins[1], 1] = True
    if side == "confined":
        fixed[mesh.nodes("side"), :2] = True
    if punch == "bonded":
        fixed[footprint, :2] = True
    tied = np.zeros((n, 3), dtype=bool)
    tied[footprint, 2] = True
    fixed[tied] = False
    return fixed, tied


def sliding_pins(mesh):
    """(node on the axis, node on the +x axis) of the bottom face, the nodes a sliding bottom is
    pinned at against rigid in-plane motion, or None if the bottom has no node on the axis (to
    1e-9 of the mesh size) and a spring of compliance C_SLIDING holds it instead."""
    bottom = mesh.nodes("bottom")
    X = mesh.points[bottom]
    tol = 1e-9 * float(np.ptp(mesh.points, axis=0).max())
    r = np.hypot(X[:, 0], X[:, 1])
    on_x = np.flatnonzero((np.abs(X[:, 1]) <= tol) & (X[:, 0] > tol))
    if r.min() > tol or on_x.size == 0:
        return None
    return int(bottom[np.argmin(r)]), int(bottom[on_x[np.argmax(X[on_x, 0])]])


def displacement_numbering(fixed, tied):
    """Reduced numbering of the 3 n displacement components: (index, sign, n_free). Free
    components are 0 .. n_free - 1 in node order, every tied one is n_free (the punch depth,
    sign -1), fixed ones are -1."""
    free = (~fixed & ~tied).ravel()
    n_free = int(free.sum())
    index = -np.ones(free.size, dtype=np.int64)
    index[free] = np.arange(n_free)
    index[tied.ravel()] = n_free
    sign = np.ones(free.size)
    sign[tied.ravel()] = -1.0
    return index, sign, n_free


def face_springs(mesh, asm, punch, support):
    """(punch_spring, bottom_spring): the tangential springs the contact and support allow
    (the frictionless footprint's, the compliant bottom's, a sliding bottom's without pins),
    None where there is none."""
    punch_spring = FaceSpring(mesh.points, mesh.facets["footprint"], asm) if punch == "frictionless" else None
    spring_below = support == "compliant" or (support == "sliding" and sliding_pins(mesh) is None)
    bottom_spring = FaceSpring(mesh.points, mesh.facets["bottom"], asm) if spring_below else None
    return punch_spring, bottom_spring
