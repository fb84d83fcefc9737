"""Relative measurements, identifiability, solvers, noise, uncertainty, hand-eye, validation,
compensation."""
