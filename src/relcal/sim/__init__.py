"""Simulation: the published experiment, synthetic images and Monte Carlo studies."""
