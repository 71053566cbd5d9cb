"""Reconstruction outputs (tools layer): fused coloured point clouds (paper Fig. 8), PLY files, depth panels and
depth / relative-pose error metrics against ground truth.

- :mod:`~codeslam.recon.fusion`: bilateral-filtered, slant-cropped back-projection of keyframe depths
  (:func:`fuse`).
- :mod:`~codeslam.recon.ply`: :func:`write_ply` / :func:`read_ply`.
- :mod:`~codeslam.recon.panels`: :func:`write_panel` of :class:`Tile`\\ s, :func:`signed_overlay` (Fig. 7).
- :mod:`~codeslam.recon.metrics`: :class:`DepthErrors`, :func:`pose_errors_relative_to_frame`.
"""

from codeslam.recon.fusion import FusionConfig, FusionView, PointCloud, fuse, view_points
from codeslam.recon.metrics import DepthErrors, PoseErrorsRelativeToFrame, pose_errors_relative_to_frame, prox_rmse

__all__ = [
    "DepthErrors", "FusionConfig", "FusionView", "PointCloud", "PoseErrorsRelativeToFrame", "fuse", "prox_rmse",
    "pose_errors_relative_to_frame", "view_points",
]
