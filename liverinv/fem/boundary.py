"""The indentation test's displacement boundary conditions, one definition for both models
(`indentation.Indentation` and `biphasic.Biphasic`).

The punch footprint's axial displacement is one unknown shared by its nodes, the punch depth
d (u_z = -d: the nodes are *tied*, numbered after the free ones with sign -1). Its tangential
motion is free (frictionless, where a tangential spring of stiffness k_punch may restrain it)
or held (bonded). The bottom face is held (fixed), holds u_z only (sliding, with two more
components held at two nodes against rigid motion), or holds u_z with a tangential spring of
compliance c_bottom (compliant). The side is free, or confined (u_x = u_y = 0, confined
compression).
"""

from __future__ import annotations

import numpy as np

from .springs import FaceSpring

__all__ = ["PUNCH_CONTACTS", "SUPPORTS", "SIDES", "check_names", "constrained_components",
           "displacement_numbering", "face_springs"]

PUNCH_CONTACTS = ("frictionless", "bonded")
SUPPORTS = ("fixed", "sliding", "compliant")
SIDES = ("free", "confined")


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
    if support == "sliding":
        # no tangential restraint: hold the rigid in-plane motion at the bottom's centre node
        # (u_x, u_y) and at its node of largest x (u_y)
        X = mesh.points[bottom]
        fixed[bottom[np.argmin(np.hypot(X[:, 0], X[:, 1]))], :2] = True
        fixed[bottom[np.argmax(X[:, 0])], 1] = True
    if side == "confined":
        fixed[mesh.nodes("side"), :2] = True
    if punch == "bonded":
        fixed[footprint, :2] = True
    tied = np.zeros((n, 3), dtype=bool)
    tied[footprint, 2] = True
    fixed[tied] = False
    return fixed, tied


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
    (the frictionless footprint's, the compliant bottom's), None where there is none."""
    punch_spring = FaceSpring(mesh.points, mesh.facets["footprint"], asm) if punch == "frictionless" else None
    bottom_spring = FaceSpring(mesh.points, mesh.facets["bottom"], asm) if support == "compliant" else None
    return punch_spring, bottom_spring
