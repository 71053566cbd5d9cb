"""Numerical constants shared by the whole package, kept in one place (cf. theseus global_params)."""

# Below this angle (radians) the SO(3) exp/log and their Jacobians switch to Taylor expansions.
SMALL_ANGLE = 1e-6
# Smallest depth (metres) treated as a valid point in front of the camera.
MIN_DEPTH = 1e-3
# Clamp for proximity values decoded by the network, so that depth = a (1 - p) / p stays finite.
MIN_PROXIMITY = 1e-4
MAX_PROXIMITY = 1.0 - 1e-4
