"""The sparse half of tracking: ORB matches between the frame and its reference keyframe, found near where the
motion model predicts them (and through the previous frame's matches, whose appearance is closer), then a pose
by PnP with RANSAC. Its pose starts the photometric alignment and its inliers enter that alignment as
reprojection residuals (:class:`~codeslam.slam.reprojection.ReprojectionTerm`); relocalisation matches a lost
frame against stored keyframes the same way without a prediction.

All pixels are in the *feature camera* (:func:`~codeslam.slam.features.scaled_camera` of the network's); a
keyframe's 3D points come from its decoded depth at its current code (:func:`keyframe_points`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from codeslam.data.frame import Frame
from codeslam.geometry.camera import PinholeCamera
from codeslam.geometry.image import image_is_finite
from codeslam.slam.config import FeatureConfig
from codeslam.slam.features import (
    Features,
    ORBExtractor,
    guided_mask,
    keyframe_points,
    match,
    project_points,
    solve_pnp,
    to_uint8,
)
from codeslam.slam.reprojection import ReprojectionTerm


@dataclass
class KeyframeFeatures:
    """A keyframe's keypoints and their 3D points in the keyframe's camera frame (NaN where the depth gives
    none); ``xyz`` follows the keyframe's code (:meth:`SparseTracker.points`)."""

    features: Features
    xyz: np.ndarray


@dataclass
class FrameMatches:
    """What a tracked frame's keypoints matched in its reference keyframe: kept for the next frame, whose
    appearance is closer to this frame's than to the keyframe's.

    Attributes:
        keyframe_id: the reference keyframe.
        features: the frame's keypoints.
        point: (N,) for each keypoint, the index of the keyframe point it matched as an inlier, or -1.
    """

    keyframe_id: int
    features: Features
    point: np.ndarray


@dataclass
class SparseTrack:
    """The sparse estimate of a frame's pose in a keyframe.

    Attributes:
        ok: PnP found a pose with enough inliers.
        T_kf: (4, 4) float64 pose of the frame in the keyframe (frame points -> keyframe), None when not ok.
        point: (M,) keyframe point indices of the inlier matches; frame_kp: (M,) the frame's keypoint indices.
        matches: correspondences before RANSAC; guided: whether they were found around a predicted pose.
    """

    ok: bool
    T_kf: torch.Tensor | None
    point: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    frame_kp: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    matches: int = 0
    guided: bool = False

    @property
    def num_inliers(self) -> int:
        return int(self.point.shape[0])


def _se3_inverse(T: np.ndarray) -> np.ndarray:
    """(4, 4) float64 -> ``[[R^T, -R^T t], [0, 1]]``, :func:`~codeslam.geometry.lie.se3_inverse` in NumPy: the
    sparse front-end works on NumPy poses, and the torch version's few small operations took 39 us a call against
    5 us (0.18 ms each inside a TUM fr1/rpy run at 2 threads, three a frame); equal to the last bit on 2,000 random
    poses on an Intel Xeon, within 2 units in the last place of the translation on an AMD EPYC (NumPy's and torch's
    3x3 products round differently there)."""
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -(R.T @ T[:3, 3])
    return out


class SparseTracker:
    """ORB extraction, guided and global matching, and PnP for one feature camera.

    cfg: thresholds; camera: the feature camera; depth_camera: the camera of the keyframes' depth maps.
    """

    def __init__(self, cfg: FeatureConfig, camera: PinholeCamera, depth_camera: PinholeCamera) -> None:
        self.cfg, self.camera, self.depth_camera = cfg, camera, depth_camera
        self.extract = ORBExtractor(cfg.n_features, fast_threshold=cfg.fast_threshold)

    def features_of(self, frame: Frame) -> Features | None:
        """Keypoints of an input frame, found in the feature camera (the frame resampled to it, so keypoints see
        its full resolution); None when the resampled image holds non-finite values."""
        from codeslam.geometry.resample import resample_image, resample_validity

        cam = self.camera
        gray = frame.gray[None].float()
        hi = gray[0] if frame.camera == cam else resample_image(gray, frame.camera, cam)[0]
        valid = resample_validity(frame.valid, frame.camera, cam) if frame.camera != cam else frame.valid
        if not image_is_finite(hi):
            return None
        return self.extract(to_uint8(hi), None if valid is None else valid.numpy())

    def points(self, features: Features, depth: torch.Tensor) -> np.ndarray:
        """(N, 3) 3D points of a keyframe's keypoints from its depth map (network camera); none beyond
        ``max_point_depth`` times the map's median depth."""
        valid = depth[torch.isfinite(depth) & (depth > 0)]
        far = math.inf if valid.numel() == 0 else self.cfg.max_point_depth * float(valid.median())
        return keyframe_points(features.uv, self.camera, depth, self.depth_camera, max_depth=far)

    def _pnp(self, xyz: np.ndarray, uv: np.ndarray, T_kf_init: torch.Tensor | None, min_inliers: int):
        T_init = None if T_kf_init is None else _se3_inverse(T_kf_init.detach().to(torch.float64).cpu().numpy())
        return solve_pnp(xyz, uv, self.camera, self.cfg.pnp_threshold, min_inliers, T_init,
                         self.cfg.ransac_iterations)

    def _result(self, pnp, pts: np.ndarray, kps: np.ndarray, guided: bool) -> SparseTrack:
        if not pnp.ok:
            return SparseTrack(False, None, matches=len(pts), guided=guided)
        T_kf = torch.from_numpy(_se3_inverse(pnp.T_ab))  # PnP gives keyframe -> frame
        return SparseTrack(True, T_kf, pts[pnp.inliers], kps[pnp.inliers], len(pts), guided)

    def track(self, kf: KeyframeFeatures, frame: Features, T_kf_pred: torch.Tensor | None,
              previous: FrameMatches | None = None, keyframe_id: int | None = None) -> SparseTrack:
        """The frame's pose in the keyframe from matches: first guided by ``T_kf_pred`` (keyframe points
        projected with the prediction, candidates within ``guided_radius``; the previous frame's descriptors of
        the same points compete with the keyframe's), then, if that finds too few inliers, global matching and
        RANSAC from scratch followed by one guided pass at the pose found."""
        cfg = self.cfg
        has_3d = np.isfinite(kf.xyz).all(1)
        if len(frame) == 0 or not has_3d.any():
            return SparseTrack(False, None)
        if T_kf_pred is not None:
            found = self._guided(kf, frame, T_kf_pred, previous, keyframe_id)
            if found.ok and found.num_inliers >= cfg.min_inliers:
                return found
        ia, ib = match(kf.features.desc, frame.desc, cfg.match_ratio, cfg.max_hamming)
        ok = has_3d[ia]
        ia, ib = ia[ok], ib[ok]
        first = self._result(self._pnp(kf.xyz[ia], frame.uv[ib], None, cfg.min_inliers), ia, ib, False)
        if not first.ok:
            return first
        again = self._guided(kf, frame, first.T_kf, previous, keyframe_id)
        return again if again.ok and again.num_inliers >= first.num_inliers else first

    def _guided(self, kf: KeyframeFeatures, frame: Features, T_kf: torch.Tensor,
                previous: FrameMatches | None, keyframe_id: int | None) -> SparseTrack:
        cfg = self.cfg
        has_3d = np.isfinite(kf.xyz).all(1)
        idx = np.nonzero(has_3d)[0]
        T_fk = _se3_inverse(T_kf.detach().to(torch.float64).cpu().numpy())
        pred = project_points(kf.xyz[idx], T_fk, self.camera)  # where the keyframe's points should appear
        allowed = guided_mask(pred, frame.uv, cfg.guided_radius)
        ia, ib, dist = match(kf.features.desc[idx], frame.desc, cfg.match_ratio, cfg.max_hamming, allowed, True)
        pts, kps, d = idx[ia], ib, dist
        if previous is not None and previous.keyframe_id == keyframe_id:
            seen = previous.point >= 0  # the previous frame's keypoints that matched a keyframe point
            seen[seen] = has_3d[previous.point[seen]]  # and whose point still has a depth at the current code
            if seen.any():
                prev_pts = previous.point[seen]
                allowed_p = allowed[np.searchsorted(idx, prev_pts)]  # the same points' rows of the mask
                pa, pb, pd = match(previous.features.desc[seen], frame.desc, cfg.match_ratio, cfg.max_hamming,
                                   allowed_p, True)
                pts, kps, d = (np.concatenate([pts, prev_pts[pa]]), np.concatenate([kps, pb]),
                               np.concatenate([d, pd]))
        if len(pts):  # one match per frame keypoint and per keyframe point: the closer descriptor wins
            order = np.argsort(d, kind="stable")
            pts, kps = pts[order], kps[order]
            _, first_k = np.unique(kps, return_index=True)
            keep = np.zeros(len(pts), bool)
            keep[first_k] = True
            _, first_p = np.unique(pts, return_index=True)
            keep_p = np.zeros(len(pts), bool)
            keep_p[first_p] = True
            keep &= keep_p
            pts, kps = pts[keep], kps[keep]
        pnp = self._pnp(kf.xyz[pts], frame.uv[kps], T_kf, cfg.min_inliers)
        return self._result(pnp, pts, kps, True)

    def term(self, kf: KeyframeFeatures, frame: Features, track: SparseTrack, dtype: torch.dtype,
             device: torch.device) -> ReprojectionTerm:
        """The reprojection residuals of the track's inliers for the alignment (keyframe = frame 0 of the
        state, the frame = frame 1); the noise grows with ORB's pyramid scale of each keypoint."""
        sigma = self.cfg.sigma * self.extract.orb.getScaleFactor() ** frame.octave[track.frame_kp]
        return ReprojectionTerm(
            0, 1, torch.from_numpy(kf.xyz[track.point]).to(dtype=dtype, device=device),
            torch.from_numpy(frame.uv[track.frame_kp]).to(dtype=dtype, device=device),
            torch.as_tensor(sigma, dtype=dtype, device=device), self.camera, weight=self.cfg.weight,
        )

    def match_keyframes(self, a: KeyframeFeatures, b: Features, T_ba: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """Matches between two keyframes whose relative pose ``T_ba`` (a's points -> b) is known: a's points
        projected into b, guided matching, and only matches within the PnP threshold kept. Returns keypoint
        indices (M,) into a's and b's features."""
        has_3d = np.isfinite(a.xyz).all(1)
        idx = np.nonzero(has_3d)[0]
        if len(idx) == 0 or len(b) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        pred = project_points(a.xyz[idx], T_ba.to(torch.float64).numpy(), self.camera)
        allowed = guided_mask(pred, b.uv, self.cfg.guided_radius)
        ia, ib = match(a.features.desc[idx], b.desc, self.cfg.match_ratio, self.cfg.max_hamming, allowed)
        ok = np.linalg.norm(pred[ia] - b.uv[ib], axis=1) <= self.cfg.pnp_threshold
        return idx[ia[ok]], ib[ok]

    def matches_for_next(self, keyframe_id: int, frame: Features, track: SparseTrack,
                         inliers: np.ndarray | None = None) -> FrameMatches:
        """The frame's keypoint -> keyframe point table for the next frame (``inliers`` (M,) bool restricts the
        track's matches to those still inliers at the final pose)."""
        point = np.full(len(frame), -1, np.int64)
        keep = np.ones(track.num_inliers, bool) if inliers is None else inliers
        point[track.frame_kp[keep]] = track.point[keep]
        return FrameMatches(keyframe_id, frame, point)

    def relocalise(self, candidates: list[tuple[int, KeyframeFeatures]], frame: Features,
                   min_inliers: int) -> tuple[int, SparseTrack] | None:
        """Global matching of the frame against each candidate keyframe (id, features) and PnP; the candidate
        with the most inliers (at least ``min_inliers``), or None."""
        best = None
        for kid, kf in candidates:
            found = self.track(kf, frame, None)
            if found.ok and found.num_inliers >= min_inliers and (best is None
                                                                  or found.num_inliers > best[1].num_inliers):
                best = (kid, found)
        return best



def poses_from_features(frames: list[Frame], master: int, master_depth: torch.Tensor, depth_camera: PinholeCamera,
                        cfg: FeatureConfig | None = None) -> tuple[torch.Tensor, list[int]]:
    """Initial poses for N-frame SfM: each frame's pose in the master's camera by global ORB matching against the
    master's keypoints (3D from ``master_depth`` (H, W) seen by ``depth_camera``, e.g. the zero-code depth) and
    PnP with RANSAC, as the tracker starts every alignment. The paper's SfM starts from the identity, which holds
    rotations of about 10 degrees (``SfMConfig.pyramid_levels``); TUM fr1/rpy masters with neighbours 6-9 frames
    away are 9-14 degrees from it and ended 15-39 degrees off.

    Returns (F, 4, 4) float64 T_master,frame (the master's own pose and frames PnP cannot place: the identity)
    and the PnP inlier count of each frame (0 where it failed)."""
    from codeslam.slam.features import scaled_camera

    cfg = cfg or FeatureConfig()
    sparse = SparseTracker(cfg, scaled_camera(depth_camera, cfg.scale), depth_camera)
    feats = [sparse.features_of(f) for f in frames]
    poses = torch.eye(4, dtype=torch.float64).repeat(len(frames), 1, 1)
    inliers = [0] * len(frames)
    if feats[master] is None:
        return poses, inliers
    kf = KeyframeFeatures(feats[master], sparse.points(feats[master], master_depth))
    for i, f in enumerate(feats):
        if i == master or f is None:
            continue
        found = sparse.track(kf, f, None)
        if found.ok:
            poses[i], inliers[i] = found.T_kf.to(torch.float64), found.num_inliers
    return poses, inliers
