"""Imaging half of liverinv: synthetic 3D ultrasound, the measurement bundle, and nodal
Lucas-Kanade motion tracking with confidence (see README.md in this folder)."""

from .bundle import Bundle, Indenter, open_bundle, write_bundle
from .flow import track_bundle
from .grid import ImageGrid, paper_grid
from .sequence import ImagingOptions, SpeckleScene
from .speckle import Transducer
from .tracking import NodalTracker, TrackOptions
from .weights import VoxelWeights

__all__ = ["Bundle", "Indenter", "open_bundle", "write_bundle", "track_bundle", "ImageGrid",
           "paper_grid", "ImagingOptions", "SpeckleScene", "Transducer", "NodalTracker",
           "TrackOptions", "VoxelWeights"]
