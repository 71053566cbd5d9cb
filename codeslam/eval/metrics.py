"""Trajectory error metrics: absolute trajectory error (ATE), relative pose error (RPE), drift against
travelled distance and KITTI-style segment errors.

Pure maths on :class:`~codeslam.data.trajectory.Trajectory` objects (numpy float64 inside): no file I/O and
no plotting (reading files is :mod:`codeslam.data.trajectory_file`, plots are :mod:`codeslam.eval.plots`).

The definitions follow evo (M. Grupp, https://github.com/MichaelGrupp/evo), the tool SLAM papers report, so
that numbers are comparable; the test suite cross-checks them against evo 1.38:

* ATE = evo_ape with its default ``translation_part`` relation: the estimate is aligned to the reference with
  Umeyama's method and the error of pose i is ``|| p_ref_i - (s R p_est_i + t) ||``.
* RPE = evo_rpe: ``E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (Q reference, P estimate); the translation error is
  ``||trans(E_ij)||`` and the rotation error the angle of ``rot(E_ij)``.

Poses are camera-to-world ``T_wc`` (the convention of :class:`Trajectory`); all distances are in the units
of the reference (metres).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

import numpy as np
import torch

from codeslam.constants import UMEYAMA_RANK_RTOL
from codeslam.data.association import associate
from codeslam.data.trajectory import Trajectory
from codeslam.errors import CodeSLAMError
from codeslam.geometry.lie import so3_log

Align = Literal["se3", "sim3", "none"]
ALIGN_MODES = ("se3", "sim3", "none")
# evo's default ``t_max_diff`` for timestamp association (seconds).
DEFAULT_MAX_DIFF = 0.01
# Umeyama needs three non-collinear points to fix a rotation; the metrics ask for at least this many matches.
MIN_MATCHES = 3


# ----------------------------------------------------------------------------------------------------------
# Statistics and similarity transforms
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ErrorStats:
    """Summary statistics of a vector of non-negative errors (the statistics evo reports)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float

    @classmethod
    def from_errors(cls, errors: np.ndarray) -> ErrorStats:
        """(N,) errors -> statistics; ``std`` is the population standard deviation (numpy's, as evo)."""
        e = np.asarray(errors, dtype=np.float64)
        return cls(
            rmse=float(np.sqrt(np.mean(e * e))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
        )

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(ErrorStats)}


@dataclass(frozen=True)
class Sim3:
    """A similarity transform ``x -> s R x + t``.

    Attributes:
        R: (3, 3) rotation. t: (3,) translation. s: scale (1 for a rigid transform).
    """

    R: np.ndarray
    t: np.ndarray
    s: float = 1.0

    def __iter__(self):
        """Unpack as ``R, t, s = sim3``."""
        return iter((self.R, self.t, self.s))

    @classmethod
    def identity(cls) -> Sim3:
        return cls(np.eye(3), np.zeros(3), 1.0)

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) ``[[s R, t], [0, 1]]``."""
        S = np.eye(4)
        S[:3, :3] = self.s * self.R
        S[:3, 3] = self.t
        return S

    def apply_points(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) points -> (..., 3) ``s R x + t``."""
        return self.s * xyz @ self.R.T + self.t

    def apply_poses(self, T: np.ndarray) -> np.ndarray:
        """(..., 4, 4) poses ``T_wc`` -> the same cameras in the transformed world: rotation ``R R_wc``,
        centre ``s R c + t`` (the frame moves rigidly, the scale acts on positions only)."""
        out = np.array(T, dtype=np.float64, copy=True)
        out[..., :3, :3] = self.R @ T[..., :3, :3]
        out[..., :3, 3] = self.apply_points(T[..., :3, 3])
        return out


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> Sim3:
    """Least-squares similarity ``dst ≈ s R src + t`` (S. Umeyama, "Least-squares estimation of transformation
    parameters between two point patterns", IEEE PAMI 13(4), 1991).

    Args:
        src: (N, 3) points, e.g. estimated camera centres.
        dst: (N, 3) corresponding points, e.g. reference camera centres.
        with_scale: estimate ``s`` too (Sim(3)); otherwise ``s = 1`` (SE(3)).
    Returns:
        :class:`Sim3` with (3, 3) ``R``, (3,) ``t`` and ``s``; it unpacks as ``R, t, s = umeyama(...)``.
    Raises:
        CodeSLAMError: fewer than 3 points, or points that are all equal or collinear (no unique rotation).
    """
    sim, D = _umeyama_fit(src, dst, with_scale)
    if D[1] <= UMEYAMA_RANK_RTOL * D[0]:
        raise CodeSLAMError(
            "cannot align trajectories: the matched positions are all equal or collinear (no unique rotation); "
            "use --align none"
        )
    return sim


def _umeyama_fit(src: np.ndarray, dst: np.ndarray, with_scale: bool) -> tuple[Sim3, np.ndarray]:
    """:func:`umeyama`'s similarity and the singular values D of the cross-covariance, without its rank check: for
    collinear points (a straight stretch of path) the scale and the residual are defined though the rotation about
    their line is not (any R of the SVD's family fits alike). Raises on fewer than 3 points or all-equal ones."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"umeyama wants two (N, 3) arrays, got {src.shape} and {dst.shape}")
    n = len(src)
    if n < MIN_MATCHES:
        raise CodeSLAMError(f"cannot align trajectories on {n} matched poses; at least {MIN_MATCHES} are needed")
    mu_src = src.mean(axis=0)  # eq. (34)
    mu_dst = dst.mean(axis=0)  # eq. (35)
    src_c = src - mu_src
    dst_c = dst - mu_dst
    var_src = np.mean(np.sum(src_c * src_c, axis=1))  # sigma_x^2, eq. (36)
    cov = dst_c.T @ src_c / n  # Sigma_xy, eq. (38)
    U, D, Vt = np.linalg.svd(cov)  # Sigma_xy = U D V^T (between eqs. 38 and 39)
    if D[0] <= 0.0 or not var_src > 0.0:
        raise CodeSLAMError(
            "cannot align trajectories: the matched positions are all equal or collinear (no unique rotation); "
            "use --align none"
        )
    S = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:  # eq. (43): reflection -> flip the smallest axis
        S[2] = -1.0
    R = (U * S) @ Vt  # R = U S V^T, eq. (40)
    s = float(np.sum(D * S) / var_src) if with_scale else 1.0  # c = tr(D S) / sigma_x^2, eq. (42)
    t = mu_dst - s * R @ mu_src  # eq. (41)
    return Sim3(R, t, s), D


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (...,) rotation angle in radians (norm of the SO(3) logarithm)."""
    R64 = torch.as_tensor(np.asarray(R, dtype=np.float64))
    # so3_log goes through the quaternion: accurate at small and large angles alike (arccos of the trace is not).
    return so3_log(R64).norm(dim=-1).numpy()


def orientation_errors_aligned(R_est: np.ndarray, R_ref: np.ndarray) -> np.ndarray:
    """(K,) angles (radians) between the reference orientations ``R_ref`` (K, 3, 3) and the estimated ones
    ``R_est`` (K, 3, 3) after the best rotation of the estimate's world frame: ``R* = argmin sum |R* R_est_k -
    R_ref_k|_F^2`` (the chordal mean, the closest rotation to ``sum R_ref_k R_est_k^T``), then
    ``angle(R_ref_k^T R* R_est_k)``. Position-free: it scores orientations whatever the translation estimate."""
    M = np.einsum("kij,klj->il", R_ref, R_est)  # sum R_ref R_est^T
    U, _, Vt = np.linalg.svd(M)
    S = np.diag([1.0, 1.0, np.linalg.det(U @ Vt)])
    R_star = U @ S @ Vt
    return rotation_angle(np.swapaxes(R_ref, -1, -2) @ R_star @ R_est)


def relative_poses(T: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses and (K,) index pairs -> (K, 4, 4) ``T_i^-1 T_j``."""
    Ti_inv = np.linalg.inv(T[i])  # general inverse: exact enough for SE(3) and keeps the code short
    return Ti_inv @ T[j]


def _align_mode(align: str) -> str:
    if align not in ALIGN_MODES:
        raise CodeSLAMError(f"unknown alignment {align!r}; expected one of {', '.join(ALIGN_MODES)}")
    return align


def align_poses(est: np.ndarray, ref: np.ndarray, align: Align) -> tuple[np.ndarray, Sim3]:
    """Align (N, 4, 4) estimated poses to (N, 4, 4) corresponding reference poses by their positions.

    Returns the aligned estimate (N, 4, 4) and the :class:`Sim3` that maps the estimate's world into the
    reference's (identity for ``'none'``).
    """
    if _align_mode(align) == "none":
        return np.array(est, copy=True), Sim3.identity()
    S = umeyama(est[:, :3, 3], ref[:, :3, 3], with_scale=align == "sim3")
    return S.apply_poses(est), S


# ----------------------------------------------------------------------------------------------------------
# Association
# ----------------------------------------------------------------------------------------------------------


def match_trajectories(
    est: Trajectory, ref: Trajectory, max_diff: float = DEFAULT_MAX_DIFF, min_matches: int = MIN_MATCHES
) -> tuple[np.ndarray, np.ndarray]:
    """Associate ``est`` with ``ref`` by timestamp, one-to-one, nearest first, pairs at most ``max_diff``
    seconds apart (:func:`codeslam.data.association.associate`, the TUM benchmark's rule). Where every
    estimate stamp has a distinct nearest reference stamp this is the same as evo's
    ``sync.associate_trajectories``; unlike evo it never matches one reference pose twice.

    Returns (K,) estimate and (K,) reference indices, increasing. Raises :class:`CodeSLAMError` when fewer
    than ``min_matches`` poses match (no time overlap, or a clock offset larger than ``max_diff``).
    """
    if not (np.isfinite(max_diff) and max_diff >= 0):
        raise CodeSLAMError(f"max_diff must be a non-negative number of seconds, got {max_diff}")
    i_est, i_ref = associate(est.timestamps, ref.timestamps, max_diff)
    if len(i_est) == 0:
        raise CodeSLAMError(
            f"no estimated pose is within {max_diff} s of a reference pose: the trajectories do not overlap in "
            f"time (estimate {est.timestamps[0]:.3f}..{est.timestamps[-1]:.3f} s, "
            f"reference {ref.timestamps[0]:.3f}..{ref.timestamps[-1]:.3f} s)"
        )
    if len(i_est) < min_matches:
        raise CodeSLAMError(
            f"only {len(i_est)} estimated poses are within {max_diff} s of a reference pose; "
            f"at least {min_matches} are needed"
        )
    return i_est, i_ref


def _matched_poses(est: Trajectory, ref: Trajectory, max_diff: float):
    i_est, i_ref = match_trajectories(est, ref, max_diff)
    P = est.poses.detach().cpu().numpy()[i_est]  # (K, 4, 4)
    Q = ref.poses.detach().cpu().numpy()[i_ref]  # (K, 4, 4)
    return i_est, i_ref, P, Q


def accumulated_distances(xyz: np.ndarray) -> np.ndarray:
    """(N, 3) positions -> (N,) travelled distance from the first one (0 at index 0)."""
    steps = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


# ----------------------------------------------------------------------------------------------------------
# ATE
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ATEResult(ErrorStats):
    """Absolute trajectory error (translation part, metres) of the aligned estimate.

    Attributes (besides the statistics):
        errors: (K,) per-pose errors. timestamps: (K,) estimate stamps of the matched poses.
        est_idx, ref_idx: (K,) matched indices. alignment: the :class:`Sim3` applied to the estimate.
        align: ``'se3' | 'sim3' | 'none'``. est_xyz: (K, 3) aligned estimate positions. ref_xyz: (K, 3).
    """

    errors: np.ndarray
    timestamps: np.ndarray
    est_idx: np.ndarray
    ref_idx: np.ndarray
    alignment: Sim3
    align: str
    est_xyz: np.ndarray
    ref_xyz: np.ndarray

    @property
    def n_matched(self) -> int:
        return len(self.errors)


def ate(est: Trajectory, ref: Trajectory, align: Align = "se3", max_diff: float = DEFAULT_MAX_DIFF) -> ATEResult:
    """Absolute trajectory error of ``est`` against ``ref`` (evo_ape, translation part).

    Poses are associated by timestamp (:func:`match_trajectories`), the estimate is aligned to the reference
    with :func:`umeyama` on the matched positions (``'se3'``: rotation and translation, ``'sim3'``: and
    scale, as ``evo_ape -a`` / ``-as``; ``'none'``: as is), and the error of pose k is
    ``|| p_ref_k - (s R p_est_k + t) ||``.
    """
    i_est, i_ref, P, Q = _matched_poses(est, ref, max_diff)
    P_aligned, S = align_poses(P, Q, align)
    est_xyz = P_aligned[:, :3, 3]
    ref_xyz = Q[:, :3, 3]
    errors = np.linalg.norm(est_xyz - ref_xyz, axis=1)  # (K,)
    stats = ErrorStats.from_errors(errors)
    return ATEResult(
        **stats.as_dict(), errors=errors, timestamps=est.timestamps[i_est], est_idx=i_est, ref_idx=i_ref,
        alignment=S, align=align, est_xyz=est_xyz, ref_xyz=ref_xyz,
    )


# ----------------------------------------------------------------------------------------------------------
# RPE
# ----------------------------------------------------------------------------------------------------------

DeltaUnit = Literal["frames", "m"]


def pairs_by_frames(n: int, delta: int, all_pairs: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, i + delta)``: consecutive ``0, d, 2d, ...`` (evo's default) or every start ``i``."""
    starts = np.arange(0, n - delta, 1 if all_pairs else delta)
    return starts, starts + delta


def pairs_by_path(xyz: np.ndarray, delta: float, rel_tol: float = 0.1, all_pairs: bool = False):
    """Index pairs about ``delta`` metres of travelled path apart, on positions (N, 3).

    Consecutive (evo's default): walk along the path and start a new pair whenever at least ``delta`` metres
    were travelled since the last one. All pairs: for every start i the j > i whose path distance is closest
    to ``delta``, kept if within ``rel_tol * delta``. Returns (K,) i and (K,) j.
    """
    dist = accumulated_distances(xyz)
    if not all_pairs:
        ids = [0]
        for k in range(1, len(dist)):
            if dist[k] - dist[ids[-1]] >= delta:
                ids.append(k)
        ids_a = np.array(ids)
        return ids_a[:-1], ids_a[1:]
    out_i, out_j = [], []
    for i in range(len(dist) - 1):
        rest = dist[i + 1:] - dist[i]
        k = int(np.argmin(np.abs(rest - delta)))
        if abs(rest[k] - delta) <= rel_tol * delta:
            out_i.append(i)
            out_j.append(i + 1 + k)
    return np.array(out_i, dtype=np.int64), np.array(out_j, dtype=np.int64)


def relative_motion_errors(P: np.ndarray, Q: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Estimated poses P (N, 4, 4), reference poses Q (N, 4, 4), pairs (K,) -> (K, 4, 4)
    ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``: the error of the estimated motion from pose i to pose j (evo's RPE
    relation), identity when the estimate moved exactly as the reference did."""
    return np.linalg.inv(relative_poses(Q, i, j)) @ relative_poses(P, i, j)


@dataclass(frozen=True)
class RPEResult:
    """Relative pose error over pose pairs.

    Attributes:
        trans: statistics of ``||trans(E)||`` in metres. rot_deg: statistics of ``angle(rot(E))`` in degrees.
        trans_errors, rot_errors_deg: (K,) per pair. pair_i, pair_j: (K,) indices into the matched poses.
        delta, delta_unit: the pair spacing. alignment: the :class:`Sim3` applied to the estimate first.
    """

    trans: ErrorStats
    rot_deg: ErrorStats
    trans_errors: np.ndarray
    rot_errors_deg: np.ndarray
    pair_i: np.ndarray
    pair_j: np.ndarray
    delta: float
    delta_unit: str
    alignment: Sim3

    @property
    def n_pairs(self) -> int:
        return len(self.trans_errors)


def rpe(
    est: Trajectory,
    ref: Trajectory,
    delta: float = 1,
    delta_unit: DeltaUnit = "frames",
    align: Align = "none",
    max_diff: float = DEFAULT_MAX_DIFF,
    all_pairs: bool = False,
    rel_delta_tol: float = 0.1,
    pairs_from_reference: bool = False,
) -> RPEResult:
    """Relative pose error of ``est`` against ``ref``, as evo_rpe.

    On the timestamp-matched poses, pairs (i, j) are chosen ``delta`` frames apart or about ``delta``
    metres of path apart (:func:`pairs_by_frames`, :func:`pairs_by_path`; the path of the aligned estimate,
    or of the reference with ``pairs_from_reference``, evo's default being the estimate), and for each pair
    ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` gives a translation error ``||trans(E)||`` (m) and a rotation error
    ``angle(rot(E))`` (degrees). A rigid alignment (``'se3'``) does not change the RPE; ``'sim3'`` rescales
    the estimate first (``evo_rpe -as``), which monocular estimates need.
    """
    if delta_unit not in ("frames", "m"):
        raise CodeSLAMError(f"unknown delta unit {delta_unit!r}; expected 'frames' or 'm'")
    if not delta > 0 or (delta_unit == "frames" and float(delta) != int(delta)):
        raise CodeSLAMError(f"delta must be a positive {'integer' if delta_unit == 'frames' else 'number'}, "
                            f"got {delta}")
    _, _, P, Q = _matched_poses(est, ref, max_diff)
    P, S = align_poses(P, Q, align)
    if delta_unit == "frames":
        i, j = pairs_by_frames(len(P), int(delta), all_pairs)
    else:
        xyz = (Q if pairs_from_reference else P)[:, :3, 3]
        i, j = pairs_by_path(xyz, float(delta), rel_delta_tol, all_pairs)
    if len(i) == 0:
        raise CodeSLAMError(
            f"no pose pairs {delta} {delta_unit} apart among the {len(P)} matched poses; use a smaller --delta"
        )
    E = relative_motion_errors(P, Q, i, j)  # (K, 4, 4)
    trans_errors = np.linalg.norm(E[:, :3, 3], axis=1)
    rot_errors_deg = np.rad2deg(rotation_angle(E[:, :3, :3]))
    return RPEResult(
        trans=ErrorStats.from_errors(trans_errors), rot_deg=ErrorStats.from_errors(rot_errors_deg),
        trans_errors=trans_errors, rot_errors_deg=rot_errors_deg, pair_i=i, pair_j=j, delta=float(delta),
        delta_unit=delta_unit, alignment=S,
    )


# ----------------------------------------------------------------------------------------------------------
# Drift against travelled distance (the paper's Fig. 9) and KITTI-style segment errors
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DriftResult:
    """Translation error against travelled ground-truth distance.

    Attributes:
        distances: (K,) path length of the matched reference poses from the first match (m).
        errors: (K,) ``|| p_ref_k - p'_est_k ||`` of the anchored or aligned estimate (m).
        timestamps: (K,) estimate stamps. anchor: ``'first' | 'aligned'``. alignment: the :class:`Sim3` used.
    """

    distances: np.ndarray
    errors: np.ndarray
    timestamps: np.ndarray
    anchor: str
    alignment: Sim3


def drift_vs_distance(
    est: Trajectory,
    ref: Trajectory,
    anchor: Literal["first", "aligned"] = "first",
    with_scale: bool = False,
    max_diff: float = DEFAULT_MAX_DIFF,
) -> DriftResult:
    """Translation error of the estimate against travelled ground-truth distance (CodeSLAM Fig. 9).

    ``anchor='first'`` (default; odometry drift): the estimate is moved rigidly so that its first matched pose
    coincides with the reference's, ``T = Q_0 P_0^-1``, so the error starts at 0 and shows accumulated drift.
    With ``with_scale`` the estimate is also scaled about its first position by the scale of a Sim(3)
    Umeyama fit over all matches (monocular estimates have no metric scale of their own).
    ``anchor='aligned'``: the estimate is aligned by Umeyama over all matches (SE(3), or Sim(3) with
    ``with_scale``), the per-pose ATE plotted against distance.

    The distance of pose k is the path length of the matched reference positions 0..k.
    """
    i_est, _, P, Q = _matched_poses(est, ref, max_diff)
    if anchor == "aligned":
        P_aligned, S = align_poses(P, Q, "sim3" if with_scale else "se3")
    elif anchor == "first":
        s = umeyama(P[:, :3, 3], Q[:, :3, 3], with_scale=True).s if with_scale else 1.0
        T = Q[0] @ np.linalg.inv(P[0])  # rigid part, maps P_0 onto Q_0
        # x -> s R_T (x - c0) + R_T c0 + t_T = Q_0's frame, scaled about the estimate's first centre c0.
        c0 = P[0, :3, 3]
        S = Sim3(T[:3, :3], T[:3, :3] @ c0 + T[:3, 3] - s * T[:3, :3] @ c0, s)
        P_aligned = S.apply_poses(P)
    else:
        raise CodeSLAMError(f"unknown drift anchor {anchor!r}; expected 'first' or 'aligned'")
    errors = np.linalg.norm(P_aligned[:, :3, 3] - Q[:, :3, 3], axis=1)
    return DriftResult(accumulated_distances(Q[:, :3, 3]), errors, est.timestamps[i_est], anchor, S)


@dataclass(frozen=True)
class SegmentError:
    """Mean relative error over all sub-trajectories of one length (KITTI odometry benchmark).

    Attributes:
        length: segment length (m). n: number of segments. trans_pct: mean ``||trans(E)|| / length`` in %.
        rot_deg_per_m: mean ``angle(rot(E)) / length`` in degrees per metre.
    """

    length: float
    n: int
    trans_pct: float
    rot_deg_per_m: float


def segment_errors(
    est: Trajectory,
    ref: Trajectory,
    lengths: tuple[float, ...],
    step: int = 1,
    with_scale: bool = False,
    max_diff: float = DEFAULT_MAX_DIFF,
) -> list[SegmentError]:
    """KITTI-style relative errors (Geiger et al., CVPR 2012, odometry devkit): for every start pose i
    (every ``step``-th; the devkit uses 10) and every length L, j is the first pose with at least L metres of
    reference path after i, and ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` gives ``||trans(E)|| / L`` and
    ``angle(rot(E)) / L``. ``with_scale`` rescales the estimate by the Sim(3) Umeyama scale first.
    Lengths with no segment are left out of the result.
    """
    _, _, P, Q = _matched_poses(est, ref, max_diff)
    if with_scale:
        P, _ = align_poses(P, Q, "sim3")
    dist = accumulated_distances(Q[:, :3, 3])
    out = []
    starts = np.arange(0, len(P), max(1, int(step)))
    for L in lengths:
        j = np.searchsorted(dist, dist[starts] + L, side="left")  # first pose at least L further on
        ok = j < len(P)
        i_ok, j_ok = starts[ok], j[ok]
        if len(i_ok) == 0:
            continue
        E = relative_motion_errors(P, Q, i_ok, j_ok)
        t_err = np.linalg.norm(E[:, :3, 3], axis=1) / L
        r_err = np.rad2deg(rotation_angle(E[:, :3, :3])) / L
        out.append(SegmentError(float(L), len(i_ok), 100.0 * float(t_err.mean()), float(r_err.mean())))
    return out


@dataclass(frozen=True)
class ScaleDrift:
    """How the estimate's scale changed along the run (monocular scale drift).

    Attributes:
        start, end: the Sim(3) scale (estimate -> reference) of the first and of the last segment, each fitted on
            its own (Umeyama, positions).
        fit_start, fit_end: each segment's RMS position residual after its own fit over the RMS extent of its
            reference positions: near 0 where the segment's motion is a similarity of the truth's, near 1 where
            the motion is lost in the estimate's noise (a camera that turns on the spot).
        n_start, n_end: matched poses in each segment.
        fraction: each segment's share of the reference path.
        max_fit: the largest ``fit_*`` at which the scales are read (:attr:`reliable`).
    """

    start: float
    end: float
    fit_start: float
    fit_end: float
    n_start: int
    n_end: int
    fraction: float
    max_fit: float

    @property
    def growth(self) -> float:
        """The estimate's scale at the end over its scale at the start, ``start / end``: 1 holds the scale, 1.3
        means the map grew 30% against the world along the run."""
        return self.start / self.end

    @property
    def reliable(self) -> bool:
        """Both segments moved enough, against the estimate's noise, for their scales to mean something."""
        return self.fit_start <= self.max_fit and self.fit_end <= self.max_fit


def _segment_scale(src: np.ndarray, dst: np.ndarray) -> tuple[float, float]:
    """(N, 3) estimated and reference positions -> the scale of their Sim(3) fit (:func:`_umeyama_fit`, collinear
    segments too) and the fit's RMS residual over the RMS extent of dst."""
    sim, _ = _umeyama_fit(src, dst, with_scale=True)
    dst_c = dst - dst.mean(axis=0)
    residual = sim.apply_points(src) - dst
    return sim.s, float(np.sqrt(np.mean(np.sum(residual**2, 1)) / np.mean(np.sum(dst_c**2, 1))))


def scale_drift(est: Trajectory, ref: Trajectory, fraction: float = 0.2, max_fit: float = 0.25,
                max_diff: float = DEFAULT_MAX_DIFF) -> ScaleDrift:
    """Scale drift of a monocular estimate: the estimate aligned (Sim(3), Umeyama over positions) to the reference
    over the first and over the last ``fraction`` of the reference path, each on its own, and the two scales
    compared (the TUM monoVO benchmark's e_s, Engel, Usenko and Cremers 2016, which aligns start and end segments
    separately). A single Sim(3) over the whole run (ATE) averages a drifting scale away and reads the drift as
    position error; this reads it directly.

    ``max_fit`` (see :class:`ScaleDrift`): measured on the SLAM suite's runs (docs/results/slam_table.md, session
    of 2026-11-30, twenty-third), every segment of the walks, corridors, hand-held paths and the HoloLens walk fits
    to 0.004-0.18 of its extent; the worse segment of each fast turn and of TUM fr1/rpy (turns on the spot, 5-35 mm
    of motion in a segment) to 0.28-0.77.

    Raises :class:`CodeSLAMError` for fewer than 3 matched poses in a segment or a segment without motion."""
    if not 0 < fraction <= 0.5:
        raise CodeSLAMError(f"scale drift: the segments' share of the path must be in (0, 0.5], got {fraction}")
    _, _, P, Q = _matched_poses(est, ref, max_diff)
    dist = accumulated_distances(Q[:, :3, 3])
    total = float(dist[-1])
    if not total > 0:
        raise CodeSLAMError("scale drift: the reference does not move")
    first = np.nonzero(dist <= fraction * total)[0]
    last = np.nonzero(dist >= (1.0 - fraction) * total)[0]
    fits = []
    for name, idx in (("first", first), ("last", last)):
        if len(idx) < MIN_MATCHES:
            raise CodeSLAMError(f"scale drift: the {name} {fraction:.0%} of the path holds {len(idx)} matched "
                                f"poses, at least {MIN_MATCHES} are needed")
        try:
            fits.append(_segment_scale(P[idx, :3, 3], Q[idx, :3, 3]))
        except CodeSLAMError:
            raise CodeSLAMError(f"scale drift: the {name} {fraction:.0%} of the path does not move") from None
    (s0, f0), (s1, f1) = fits
    return ScaleDrift(s0, s1, f0, f1, len(first), len(last), float(fraction), float(max_fit))


def scale_drift_or_none(est: Trajectory, ref: Trajectory, max_diff: float = DEFAULT_MAX_DIFF) -> float | None:
    """:attr:`ScaleDrift.growth` of :func:`scale_drift` at its defaults (first and last 20% of the path), or None
    where it cannot be read (too few poses, a segment without motion, or not :attr:`ScaleDrift.reliable`)."""
    try:
        drift = scale_drift(est, ref, max_diff=max_diff)
    except CodeSLAMError:
        return None
    return drift.growth if drift.reliable else None


# ----------------------------------------------------------------------------------------------------------
# Everything at once (what `codeslam eval` and the SLAM runner report)
# ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Evaluation:
    """ATE, RPE and drift of one estimate, evaluated with the same association and alignment."""

    ate: ATEResult
    rpe: RPEResult
    drift: DriftResult
    max_diff: float

    def summary(self) -> dict:
        """JSON-ready dict: ``ate_{rmse,mean,median,std,min,max}``, ``rpe_trans_*`` (m), ``rpe_rot_*_deg``,
        ``n_matched``, ``align``, ``scale``, ``rotation``, ``translation`` (the alignment), ``rpe_delta``,
        ``rpe_delta_unit``, ``rpe_n_pairs``, ``max_diff``, ``path_length_gt`` (path length of the matched
        reference poses, m) and ``drift_end_error`` (error at the last pose with the first pose anchored, m)."""
        a, r, d = self.ate, self.rpe, self.drift
        out: dict = {f"ate_{k}": v for k, v in a.as_dict().items()}
        out.update({f"rpe_trans_{k}": v for k, v in r.trans.as_dict().items()})
        out.update({f"rpe_rot_{k}_deg": v for k, v in r.rot_deg.as_dict().items()})
        out.update(
            n_matched=a.n_matched,
            align=a.align,
            scale=float(a.alignment.s),
            rotation=a.alignment.R.tolist(),
            translation=a.alignment.t.tolist(),
            rpe_delta=r.delta,
            rpe_delta_unit=r.delta_unit,
            rpe_n_pairs=r.n_pairs,
            max_diff=self.max_diff,
            path_length_gt=float(d.distances[-1]),
            drift_end_error=float(d.errors[-1]),
        )
        return out


def evaluate(
    est: Trajectory,
    ref: Trajectory,
    align: Align = "se3",
    delta: float = 1,
    delta_unit: DeltaUnit = "frames",
    max_diff: float = DEFAULT_MAX_DIFF,
) -> Evaluation:
    """:func:`ate` with ``align``, :func:`rpe` on the estimate aligned the same way, and
    :func:`drift_vs_distance` anchored at the first pose (scaled by the Sim(3) fit when ``align='sim3'``)."""
    return Evaluation(
        ate=ate(est, ref, align=align, max_diff=max_diff),
        rpe=rpe(est, ref, delta=delta, delta_unit=delta_unit, align=align, max_diff=max_diff),
        drift=drift_vs_distance(est, ref, anchor="first", with_scale=align == "sim3", max_diff=max_diff),
        max_diff=max_diff,
    )
