"""Sparse features for tracking and relocalisation: ORB keypoints and descriptors, descriptor matching (plain or
guided by a predicted pose) and PnP with RANSAC, all through OpenCV.

Why features in a direct system. The photometric alignment of Sec. 4.2 converges only when it starts within a
few pixels of the optimum. Measured on the real HoloLens walk (oracle depth, frames three apart: 17-35 cm,
up to 36 deg): from the identity 11 of 19 alignments fail, from the pose of ORB + PnP on the keyframe's depth
all 19 converge. So the sparse front-end gives the initial guess and the relocalisation that the direct
back-end lacks, as ORB-SLAM's tracking does, and its matches enter the alignment as reprojection residuals
beside the photometric ones, as DeepFactors' sparse geometric factors do (:mod:`codeslam.slam.reprojection`).

Features are found in a *feature camera*: the network's canonical camera (same optical centre, axes and field
of view) scaled by an integer factor, so that a feature pixel maps to a network pixel by an affine map and a
keyframe's decoded depth gives each keypoint its 3D point (:func:`keyframe_points`). Pixel coordinates follow
the package's convention (pixel (0, 0) is the centre of the top-left pixel), which is OpenCV's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from codeslam.geometry.camera import PinholeCamera
from codeslam.geometry.lie import se3_inverse

# ORB descriptors are 256-bit strings (32 bytes); distances are Hamming distances in [0, 256].
DESCRIPTOR_BYTES = 32


def _cv2():
    """OpenCV, imported on first use (the package imports without it being loaded)."""
    import cv2

    return cv2


def scaled_camera(camera: PinholeCamera, scale: int) -> PinholeCamera:
    """``camera`` with ``scale`` times as many pixels along each axis, the same field of view and centre: a pixel
    centre ``u`` of ``camera`` lies at ``scale (u + 0.5) - 0.5`` in the scaled one."""
    return PinholeCamera(fx=camera.fx * scale, fy=camera.fy * scale, cx=scale * (camera.cx + 0.5) - 0.5,
                         cy=scale * (camera.cy + 0.5) - 0.5, width=camera.width * scale,
                         height=camera.height * scale)


def to_uint8(gray: torch.Tensor) -> np.ndarray:
    """(1, H, W) or (H, W) grey image in [0, 1] -> (H, W) uint8 (OpenCV's detectors take 8-bit images)."""
    g = gray.detach().to(device="cpu", dtype=torch.float32)
    g = g[0] if g.dim() == 3 else g
    return (g.clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8).numpy()


@dataclass
class Features:
    """Keypoints of one image.

    Attributes:
        uv: (N, 2) float64 pixel positions in the feature camera.
        desc: (N, 32) uint8 ORB descriptors.
        octave: (N,) int32 pyramid octave each keypoint was found at (its position error grows with it).
    """

    uv: np.ndarray
    desc: np.ndarray
    octave: np.ndarray

    def __len__(self) -> int:
        return int(self.uv.shape[0])

    @staticmethod
    def empty() -> Features:
        return Features(np.zeros((0, 2)), np.zeros((0, DESCRIPTOR_BYTES), np.uint8), np.zeros(0, np.int32))

    def subset(self, idx: np.ndarray) -> Features:
        return Features(self.uv[idx], self.desc[idx], self.octave[idx])


class ORBExtractor:
    """ORB keypoints spread over the image (OpenCV's FAST + Harris ranking + rBRIEF).

    n_features: keypoints per image; scale_factor, n_levels: ORB's image pyramid; fast_threshold: FAST's
    intensity threshold (lower finds keypoints on low-contrast indoor surfaces); edge: pixels kept from the
    border and from invalid pixels (the descriptor's patch must lie on real pixels).
    """

    def __init__(self, n_features: int = 1000, scale_factor: float = 1.2, n_levels: int = 8,
                 fast_threshold: int = 12, edge: int = 16) -> None:
        cv2 = _cv2()
        self.edge = edge
        self._mask: tuple[np.ndarray, np.ndarray] | None = None  # the last validity and its eroded mask
        self.orb = cv2.ORB_create(nfeatures=n_features, scaleFactor=scale_factor, nlevels=n_levels,
                                  edgeThreshold=edge, patchSize=31, fastThreshold=fast_threshold)

    def __call__(self, gray_u8: np.ndarray, valid: np.ndarray | None = None) -> Features:
        """(H, W) uint8 image and optional (H, W) bool validity -> its :class:`Features`."""
        cv2 = _cv2()
        mask = None
        if valid is not None and not bool(valid.all()):
            # A reader that masks a fixed border (undistortion) gives every frame the same validity: its erosion
            # is kept (0.29 ms a frame at 512x384 against 0.02 ms for the comparison).
            if self._mask is None or not np.array_equal(self._mask[0], valid):
                k = 2 * self.edge + 1  # keep the descriptor patches off the invalid pixels
                self._mask = (valid.copy(), cv2.erode(valid.astype(np.uint8) * 255, np.ones((k, k), np.uint8)))
            mask = self._mask[1]
        kps, desc = self.orb.detectAndCompute(gray_u8, mask)
        if desc is None or not kps:
            return Features.empty()
        uv = np.array([k.pt for k in kps], dtype=np.float64)
        octave = np.array([k.octave for k in kps], dtype=np.int32)
        return Features(uv, desc, octave)


def match(desc_a: np.ndarray, desc_b: np.ndarray, ratio: float, max_distance: int,
          allowed: np.ndarray | None = None, with_distances: bool = False):
    """Nearest-neighbour matches of a's descriptors in b with Lowe's ratio test and a distance bound, each b
    used once (the closer a wins). ``allowed`` (Na, Nb) bool restricts the candidates (guided matching).
    Returns index arrays (M,), (M,) into a and b (and their Hamming distances (M,) with ``with_distances``)."""
    cv2 = _cv2()
    none = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if len(desc_a) == 0 or len(desc_b) < 2:
        return (*none, np.zeros(0)) if with_distances else none
    # OpenCV's mask is 8-bit: a C-contiguous bool array is one already (0/1 bytes), viewed without a copy
    mask = None if allowed is None else np.ascontiguousarray(allowed, dtype=bool).view(np.uint8)
    # The two nearest of each a as arrays (what BFMatcher.knnMatch computes, through the same batchDistance, but
    # without a Python object per match: measured 4.2 -> 1.6 ms alone for 1,000 x 1,000 TUM keypoints, guided, and
    # 2.0 -> 1.4 ms per call within a SLAM run).
    # No candidate: index -1 (and INT_MAX); one candidate: its second is -1.
    dist, nidx = cv2.batchDistance(desc_a, desc_b, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2, mask=mask)
    best, second = dist[:, 0].astype(np.float64), dist[:, 1].astype(np.float64)
    ok = (nidx[:, 0] >= 0) & (best <= max_distance) & ((nidx[:, 1] < 0) | (best < ratio * second))
    ia_ = np.nonzero(ok)[0]
    if len(ia_) == 0:
        return (*none, np.zeros(0)) if with_distances else none
    ib_, d_ = nidx[ia_, 0], best[ia_]
    order = np.argsort(d_, kind="stable")  # each b once: keep its closest a
    _, first = np.unique(ib_[order], return_index=True)
    keep = np.sort(order[first])
    out = (ia_[keep].astype(np.int64), ib_[keep].astype(np.int64))
    return (*out, d_[keep]) if with_distances else out


def guided_mask(uv_pred: np.ndarray, uv_b: np.ndarray, radius: float) -> np.ndarray:
    """(Na, 2) predicted positions of a's points in b, (Nb, 2) b's keypoints -> (Na, Nb) bool, True where a b
    keypoint lies within ``radius`` pixels of the prediction (non-finite predictions allow nothing)."""
    # |a - b|^2 <= r^2  <=>  2 a.b - |b|^2 >= |a|^2 - r^2: one (Na, 3) x (3, Nb) product of [2a, -1] and [b, |b|^2]
    # and one comparison with a per-row threshold, the fewest passes over the (Na, Nb) array (measured on
    # 1000 x 1000 random points: 6.6 -> 2.1 ms against |a|^2 + |b|^2 - 2 a.b summed in three passes, itself a
    # quarter of the time of the (Na, Nb, 2) difference array). In float32: the cancellation error is a few ulp
    # of |uv|^2, under 1 px^2 for images up to 2000 px wide, against the radius^2 of hundreds of px^2. A
    # non-finite prediction gets a NaN threshold, and NaN compares False.
    a, b = uv_pred.astype(np.float32), uv_b.astype(np.float32)
    a_aug = np.empty((len(a), 3), np.float32)
    a_aug[:, :2], a_aug[:, 2] = np.float32(2.0) * a, np.float32(-1.0)
    b_aug = np.empty((len(b), 3), np.float32)
    b_aug[:, :2], b_aug[:, 2] = b, (b * b).sum(1)
    thr = np.where(np.isfinite(a).all(1), (a * a).sum(1) - np.float32(radius * radius), np.float32(np.nan))
    # The product in torch, not NumPy: NumPy's OpenBLAS runs a thread pool of its own whose workers spin for a
    # while after every call, beside torch's threads and the mapping thread (a parallel TUM fr1/rpy run on 2 cores:
    # 10-12 of 41 s of CPU in one OpenBLAS worker; the wall time alone moved within noise, since the worker yields,
    # but it left no idle core for reading ahead). torch keeps to the calling thread's share of the cores. NaN
    # compares False in either.
    prod = torch.from_numpy(a_aug) @ torch.from_numpy(b_aug).T
    return (prod >= torch.from_numpy(thr)[:, None]).numpy()


def project_points(xyz: np.ndarray, T_ba: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """(N, 3) points of frame a, (4, 4) ``T_ba`` -> (N, 2) pixels in b (NaN behind the camera)."""
    x = xyz @ T_ba[:3, :3].T + T_ba[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * x[:, 0] / x[:, 2] + camera.cx
        v = camera.fy * x[:, 1] / x[:, 2] + camera.cy
    uv = np.stack([u, v], 1)
    uv[x[:, 2] <= 1e-6] = np.nan
    return uv


def keyframe_points(uv: np.ndarray, feature_camera: PinholeCamera, depth: torch.Tensor,
                    depth_camera: PinholeCamera, max_depth_ratio: float = 1.15,
                    max_depth: float = math.inf) -> np.ndarray:
    """3D points (in the keyframe's camera frame) of keypoints ``uv`` (N, 2) of the feature camera, from the
    keyframe's ``depth`` (H, W) seen by ``depth_camera`` (same field of view, fewer pixels). Depth is read
    bilinearly; a keypoint whose four depth neighbours differ by more than ``max_depth_ratio`` (a depth edge,
    where the interpolated depth belongs to neither surface), include an invalid depth or lie beyond
    ``max_depth`` gets NaN. Returns (N, 3) float64."""
    d = depth.detach().to(device="cpu", dtype=torch.float64).numpy()
    H, W = d.shape
    s = feature_camera.width / depth_camera.width
    u = (uv[:, 0] + 0.5) / s - 0.5  # feature pixel -> depth pixel (same field of view)
    v = (uv[:, 1] + 0.5) / s - 0.5
    u0 = np.clip(np.floor(u).astype(np.int64), 0, W - 2)
    v0 = np.clip(np.floor(v).astype(np.int64), 0, H - 2)
    fu, fv = np.clip(u - u0, 0.0, 1.0), np.clip(v - v0, 0.0, 1.0)
    q = np.stack([d[v0, u0], d[v0, u0 + 1], d[v0 + 1, u0], d[v0 + 1, u0 + 1]], 1)  # (N, 4)
    z = (q[:, 0] * (1 - fu) * (1 - fv) + q[:, 1] * fu * (1 - fv) + q[:, 2] * (1 - fu) * fv
         + q[:, 3] * fu * fv)
    ok = np.isfinite(q).all(1) & (q > 0).all(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ok &= (q.max(1) <= max_depth_ratio * q.min(1)) & (q.max(1) <= max_depth)
    x = (uv[:, 0] - feature_camera.cx) / feature_camera.fx * z
    y = (uv[:, 1] - feature_camera.cy) / feature_camera.fy * z
    xyz = np.stack([x, y, z], 1)
    xyz[~ok] = np.nan
    return xyz


@dataclass
class PnPResult:
    """A pose from 2D-3D correspondences.

    Attributes:
        ok: whether RANSAC found a pose with at least the required inliers.
        T_ab: (4, 4) float64, maps the points' frame a into the camera b (``T_ba`` in the caller's naming is
            the same thing: points of frame a seen from b); identity when not ok.
        inliers: (N,) bool over the correspondences passed in.
    """

    ok: bool
    T_ab: np.ndarray
    inliers: np.ndarray

    @property
    def num_inliers(self) -> int:
        return int(self.inliers.sum())


def solve_pnp(xyz: np.ndarray, uv: np.ndarray, camera: PinholeCamera, threshold_px: float, min_inliers: int,
              T_init: np.ndarray | None = None, iterations: int = 100, confidence: float = 0.999) -> PnPResult:
    """Pose of the camera that sees points ``xyz`` (N, 3) at pixels ``uv`` (N, 2): RANSAC over minimal sets
    (OpenCV's solvePnPRansac; from ``T_init`` (4, 4), points to camera, when given), then Levenberg-Marquardt
    on the inliers. ``threshold_px``: the inlier reprojection error."""
    cv2 = _cv2()
    n = xyz.shape[0]
    fail = PnPResult(False, np.eye(4), np.zeros(n, bool))
    if n < max(min_inliers, 6):
        return fail
    K = camera.K(torch.float64).numpy()
    obj, img = np.ascontiguousarray(xyz, np.float64), np.ascontiguousarray(uv, np.float64)
    kwargs = dict(iterationsCount=iterations, reprojectionError=threshold_px, confidence=confidence)
    if T_init is not None:
        rvec0, _ = cv2.Rodrigues(np.ascontiguousarray(T_init[:3, :3]))
        tvec0 = T_init[:3, 3].reshape(3, 1).copy()
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, K, None, rvec0, tvec0, useExtrinsicGuess=True,
                                                 flags=cv2.SOLVEPNP_ITERATIVE, **kwargs)
    else:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, K, None, flags=cv2.SOLVEPNP_EPNP, **kwargs)
    if not ok or inl is None or len(inl) < min_inliers:
        return fail
    idx = inl[:, 0]
    rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], K, None, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, tvec[:, 0]
    if not np.isfinite(T).all():
        return fail
    err = np.linalg.norm(project_points(obj, T, camera) - img, axis=1)  # inliers at the refined pose
    inliers = np.isfinite(err) & (err <= threshold_px)
    if int(inliers.sum()) < min_inliers:
        return fail
    return PnPResult(True, T, inliers)


def pose_distance(T_a: torch.Tensor, T_b: torch.Tensor) -> tuple[float, float]:
    """(4, 4) poses -> (translation distance, rotation angle in degrees) of ``T_a^-1 T_b``."""
    from codeslam.geometry.lie import so3_angle_host

    D = se3_inverse(T_a.to(torch.float64)) @ T_b.to(torch.float64)
    return float(D[:3, 3].norm()), math.degrees(so3_angle_host(D[:3, :3]))
