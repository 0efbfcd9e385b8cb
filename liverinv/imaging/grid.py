"""The image grid: voxel centres in mesh coordinates (SI metres).

Axis order of every volume array is (lateral, elevational, axial) = mesh (x, y, z): the
probe sits below the tissue looking up, so the axial axis points along mesh +z.
Voxel ``(i, j, k)`` has its centre at ``origin_m + (i, j, k) * spacing_m``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["ImageGrid", "AXES", "paper_grid"]

AXES = ("lateral", "elevational", "axial")


@dataclass(frozen=True)
class ImageGrid:
    """A regular voxel grid placed in mesh coordinates.

    Parameters
    ----------
    shape : tuple of int
        Voxels along (lateral, elevational, axial).
    spacing_m : tuple of float
        Voxel size along each axis in metres.
    origin_m : tuple of float
        Mesh coordinates of the centre of voxel (0, 0, 0) in metres.
    direction : (3, 3) array-like, optional
        Column a is the unit vector, in mesh coordinates, of image axis a (orthonormal).
        Default identity: lateral = x, elevational = y, axial = z.
    """

    shape: tuple
    spacing_m: tuple
    origin_m: tuple
    direction: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

    def __post_init__(self):
        object.__setattr__(self, "shape", tuple(int(s) for s in self.shape))
        object.__setattr__(self, "spacing_m", tuple(float(s) for s in self.spacing_m))
        object.__setattr__(self, "origin_m", tuple(float(s) for s in self.origin_m))
        R = np.asarray(self.direction, dtype=float).reshape(3, 3)
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
            raise ValueError("image direction matrix is not orthonormal")
        object.__setattr__(self, "direction", tuple(map(tuple, R)))

    @property
    def R(self) -> np.ndarray:
        """Direction matrix (3, 3): columns are the image axes in mesh coordinates."""
        return np.asarray(self.direction)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def axis_m(self, a: int) -> np.ndarray:
        """Coordinates (m) of the voxel centres along axis `a`."""
        return self.origin_m[a] + self.spacing_m[a] * np.arange(self.shape[a])

    def centres(self, flat_index=None) -> np.ndarray:
        """Voxel centres (n, 3) in metres, of all voxels (C order) or of `flat_index`."""
        if flat_index is None:
            flat_index = np.arange(self.size)
        ijk = np.stack(np.unravel_index(flat_index, self.shape), axis=1)
        return self.to_m(ijk)

    def to_vox(self, x_m: np.ndarray) -> np.ndarray:
        """Continuous voxel coordinates of points given in metres."""
        return ((np.asarray(x_m) - np.asarray(self.origin_m)) @ self.R) / np.asarray(self.spacing_m)

    def to_m(self, ijk) -> np.ndarray:
        """Metres of (continuous) voxel coordinates."""
        return np.asarray(self.origin_m) + (np.asarray(ijk, dtype=float) * np.asarray(self.spacing_m)) @ self.R.T

    def vec_to_m(self, v_vox) -> np.ndarray:
        """A displacement given in voxels along the image axes, in metres along mesh axes."""
        return (np.asarray(v_vox) * np.asarray(self.spacing_m)) @ self.R.T

    def vec_to_vox(self, v_m) -> np.ndarray:
        """A displacement in metres (mesh axes), in voxels along the image axes."""
        return (np.asarray(v_m) @ self.R) / np.asarray(self.spacing_m)

    def inside(self, x_m: np.ndarray, margin_vox: float = 0.0) -> np.ndarray:
        """True where points (metres) lie within the volume, `margin_vox` voxels from its faces."""
        v = self.to_vox(x_m)
        hi = np.asarray(self.shape) - 1 - margin_vox
        return np.all((v >= margin_vox) & (v <= hi), axis=-1)


def paper_grid(shape=(128, 48, 204), spacing_m=(0.5e-3, 0.5e-3, 0.3e-3),
               standoff_m=10e-3) -> ImageGrid:
    """The seed paper's volume (section 2.1.2), centred laterally and elevationally on the
    punch axis, with `standoff_m` of stand-off pad in view below the tissue (z < 0)."""
    origin = (-(shape[0] - 1) / 2 * spacing_m[0], -(shape[1] - 1) / 2 * spacing_m[1], -standoff_m)
    return ImageGrid(shape, spacing_m, origin)
