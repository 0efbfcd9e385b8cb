"""liverinv: identify soft-tissue constitutive laws from indentation imaged by 3D ultrasound."""

__version__ = "0.1.0"
