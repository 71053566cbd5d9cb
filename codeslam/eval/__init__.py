"""Evaluation of trajectories (ATE, RPE, drift against travelled distance) and its plots; the trajectories and their
files are in :mod:`codeslam.data`."""
