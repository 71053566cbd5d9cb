"""Trajectories and their evaluation (ATE, RPE, drift against travelled distance)."""
