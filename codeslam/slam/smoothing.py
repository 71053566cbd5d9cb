"""The written trajectory's positions smoothed over the whole run: a discrete cubic smoothing spline.

Tracking places each frame against its keyframe alone, and where a small rotation and a small translation move
the image alike (a camera looking 2-3 m away) the tracked positions zig-zag by millimetres to centimetres from
frame to frame while the camera moves smoothly (TUM fr1/rpy: estimated steps of +16, -21, +24 and -11 mm along one
axis where the camera moved under 1 mm per frame; docs/results/slam_table.md). The tracker's motion prior holds
this only from the past. Once the run has ended, the positions ``z_k`` of the measured (tracked or relocalised)
frames at times ``t_k`` are replaced by the minimiser of::

    sum_k m_k |x_k - z_k|^2  +  tau^4 sum_k |a_k|^2,
    a_k = ((x_{k+1} - x_k) / dt_k - (x_k - x_{k-1}) / dt_{k-1}) / ((dt_{k-1} + dt_k) / 2)

(``m_k`` 1 for a measured frame, 0 for a predicted one; ``a_k`` the discrete acceleration): Whittaker's and
Reinsch's smoothing spline, the posterior mean of a white-noise-on-acceleration motion prior (the continuous
version of the tracker's constant-velocity model) given positions whose noise is ``tau^2`` times the prior's
acceleration noise. ``tau`` (seconds) is the time scale below which motion is taken for tracking noise: a path
that is linear in time is left as it is, whatever its speed. Both sums grow with the frame rate alike, so the
balance does not depend on it. A map segment's first frame (the world's origin for the first segment) stays
where it is. The rotations are left as tracked: the same spline on them (Gauss-Newton on SO(3)) took TUM fr1/rpy's
rotation RPE from 0.61 to 0.41 degrees per frame but the generator's hand-held one from 0.03 to 0.40, whose shake
is real rotation that tracking measures to a few hundredths of a degree (docs/results/slam_table.md).
"""

from __future__ import annotations

import numpy as np


def _second_difference_bands(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n,) increasing times -> the three coefficients (n - 2,) each of ``a_k`` on ``x_{k-1}, x_k, x_{k+1}``."""
    dt = np.diff(t)
    mid = 0.5 * (dt[:-1] + dt[1:])
    lo = 1.0 / (dt[:-1] * mid)
    hi = 1.0 / (dt[1:] * mid)
    return lo, -(lo + hi), hi


def solve_pentadiagonal(d0: np.ndarray, d1: np.ndarray, d2: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``M x = b`` for a symmetric positive definite M given by its diagonal d0 (n,), first and second
    super-diagonals d1 (n - 1,), d2 (n - 2,), and b (n, k); by the banded Cholesky factor ``M = L L^T`` (L lower
    with two sub-diagonals). Written by hand for a measured reason: the system has one row per frame, a dense solve
    is cubic in time and quadratic in memory (a 10,000-frame run: 800 MB), and the package's dependencies have no
    banded solver (SciPy is a test dependency only). O(n)."""
    n = d0.shape[0]
    l0, l1, l2 = np.zeros(n), np.zeros(n), np.zeros(n)  # L[i, i], L[i, i - 1], L[i, i - 2]
    for i in range(n):
        if i >= 2:
            l2[i] = d2[i - 2] / l0[i - 2]
        if i >= 1:
            l1[i] = (d1[i - 1] - l2[i] * l1[i - 1]) / l0[i - 1]
        piv = d0[i] - l1[i] ** 2 - l2[i] ** 2
        if not piv > 0:
            raise np.linalg.LinAlgError("the smoothing system is not positive definite")
        l0[i] = np.sqrt(piv)
    y = np.array(b, dtype=np.float64)
    for i in range(n):  # L y = b
        if i >= 1:
            y[i] -= l1[i] * y[i - 1]
        if i >= 2:
            y[i] -= l2[i] * y[i - 2]
        y[i] /= l0[i]
    for i in range(n - 1, -1, -1):  # L^T x = y
        if i + 1 < n:
            y[i] -= l1[i + 1] * y[i + 1]
        if i + 2 < n:
            y[i] -= l2[i + 2] * y[i + 2]
        y[i] /= l0[i]
    return y


def smooth_positions(t: np.ndarray, z: np.ndarray, measured: np.ndarray, tau: float,
                     anchor: bool = False) -> np.ndarray:
    """The smoothing spline of the module docstring: t (n,) times (s), z (n, 3) positions, measured (n,) bool
    -> (n, 3). ``anchor``: the first position is held where it is (a map's origin, which defines the world rather
    than measures it). Returned unchanged when ``tau`` is 0, when fewer than three frames are given, when too few
    are measured to fix a line (two, or one besides the anchor), or when the times do not increase strictly (no
    time scale to smooth on)."""
    z = np.asarray(z, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    m = np.asarray(measured, dtype=np.float64)
    n = z.shape[0]
    enough = int((m[1:] > 0).sum()) >= 1 if anchor else int((m > 0).sum()) >= 2
    if tau <= 0 or n < 3 or not enough or not bool(np.all(np.diff(t) > 0)):
        return z.copy()
    lo, mid, hi = _second_difference_bands(t)
    lam = tau**4
    d0 = m.copy()
    d0[:-2] += lam * lo**2
    d0[1:-1] += lam * mid**2
    d0[2:] += lam * hi**2
    d1 = np.zeros(n - 1)
    d1[:-1] += lam * lo * mid  # (k - 1, k) of row k
    d1[1:] += lam * mid * hi  # (k, k + 1)
    d2 = lam * lo * hi  # (k - 1, k + 1)
    b = m[:, None] * z
    if not anchor:
        return solve_pentadiagonal(d0, d1, d2, b)
    b[1] -= d1[0] * z[0]  # x_0 = z_0 known: its columns move to the right-hand side
    b[2] -= d2[0] * z[0]
    return np.concatenate([z[:1], solve_pentadiagonal(d0[1:], d1[1:], d2[1:], b[1:])])
