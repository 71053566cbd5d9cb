"""Numerical constants shared by the whole package, kept in one place (cf. theseus global_params)."""

# Below this angle (radians) the SO(3) exp/log and their Jacobians switch to Taylor expansions.
SMALL_ANGLE = 1e-6
# Below this angle the SO(3) Jacobian coefficients (t - sin t)/t^3 and 1/t^2 - cot(t/2)/(2t), which cancel
# catastrophically in float32 (measured: autograd of se3_exp off by 5e-2 at t = 1e-6), use their Taylor series
# through t^8, which is exact to float64 rounding up to this angle.
SERIES_ANGLE = 0.1
# Smallest depth (metres) treated as a valid point in front of the camera.
MIN_DEPTH = 1e-3
# Reprojection residuals of matched keypoints: a point counts as in front of the camera above this depth.
MIN_KEYPOINT_DEPTH = 1e-6
# Clamp for proximity values decoded by the network, so that depth = a (1 - p) / p stays finite.
MIN_PROXIMITY = 1e-4
MAX_PROXIMITY = 1.0 - 1e-4
# Umeyama alignment: the point cross-covariance counts as rank-deficient (collinear or coincident points, no
# unique rotation) when its second singular value is below this fraction of the first.
UMEYAMA_RANK_RTOL = 1e-10
# Resampling that shrinks the image by more than this factor (source pixels per destination pixel) is
# anti-aliased first: below 2x every source pixel still falls inside some destination pixel's bilinear footprint.
ANTIALIAS_MIN_SHRINK = 2.0
# Floor of the network's Laplace scale b (proximity units) so that |p - mu| / b + log b stays finite.
MIN_UNCERTAINTY = 1e-3
# SfM: a bilinear lookup of a 0/1 validity image counts as "all four neighbours valid" above this (rounding slack).
BILINEAR_ALL_VALID = 1.0 - 1e-6
# SfM: floor of the Levenberg-Marquardt damping factor, so repeated decreases never underflow to 0.
MIN_LM_DAMPING = 1e-12
