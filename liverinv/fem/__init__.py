"""Finite-strain finite-element engine: discrete space, constitutive kernels, assembly,
boundary conditions and the Newton solver. One engine serves every study."""
