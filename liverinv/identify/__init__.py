"""Identification: the velocity-based objective (seed paper Eqs. 3-5) and the optimizers."""
