"""Geometry: Lie groups, the pinhole camera, proximity and image pyramids, as small pure torch functions."""
