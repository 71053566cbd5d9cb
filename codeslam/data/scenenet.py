"""SceneNet RGB-D trajectories (McCormac et al., ICCV 2017): the synthetic data CodeSLAM trained on.

Layout of one trajectory (``root``), as unpacked from the dataset's archives::

    <split>/<n>/<traj>/photo/<frame_num>.jpg      colour, 320x240
    <split>/<n>/<traj>/depth/<frame_num>.png      16-bit, millimetres, Euclidean *ray length*, 0 = no hit
    <split>/<n>/<traj>/instance/<frame_num>.png   (not used)
    scenenet_rgbd_<split>_<n>.pb                  poses of every trajectory of the archive (protobuf)

The protobuf file is given with ``protobuf=`` or found as the first ``*.pb`` in ``root`` or one of its two
parent folders that holds a trajectory whose ``render_path`` (e.g. ``"0/223"``) names ``root``.

- **Depth.** SceneNet stores the distance along each pixel's ray, not z; it is converted with
  ``z = r / ||K^-1 (u, v, 1)||`` (:func:`ray_length_to_z`).
- **Pose.** Each view gives a look-at camera at shutter open and shutter close; the frame is rendered
  over that interval, so the pose (and timestamp) is taken halfway: camera position and look-at point are
  averaged, then the OpenCV camera frame is built with z toward the look-at point, x = z x up, y = z x x,
  with world up = +y as SceneNet does (:func:`look_at_pose`). The SceneNet scripts do the same.
- **Camera.** 320x240, 60 deg horizontal and 45 deg vertical field of view: fx = 160 / tan 30 deg,
  fy = 120 / tan 22.5 deg (non-square pixels). The renderer's rays pass through pixel centres
  ``(x + 0.5) / 320`` of a symmetric frustum, so in our pixel-centre convention cx = 159.5, cy = 119.5
  (the SceneNet example script's K writes 160, 120, half a pixel off).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from codeslam.data.base import ImageFileSequence
from codeslam.data.imageio import check_depth_shape, read_depth_png, require_file
from codeslam.data.scenenet_proto import read_trajectories
from codeslam.errors import DatasetError
from codeslam.geometry.camera import PinholeCamera, pixel_grid, unproject_jac_depth

#: SceneNet depth PNGs are millimetres.
SCENENET_DEPTH_FACTOR = 1000.0
#: The renderer's camera (see the module docstring for cx, cy).
SCENENET_CAMERA = PinholeCamera(
    fx=160.0 / math.tan(math.radians(30.0)),
    fy=120.0 / math.tan(math.radians(22.5)),
    cx=159.5,
    cy=119.5,
    width=320,
    height=240,
)
#: SceneNet's world up direction, used to complete the look-at frame.
SCENENET_UP = (0.0, 1.0, 0.0)
#: A view whose look-at direction is shorter than this (metres), or within this sine of the up
#: direction, has no defined camera frame.
LOOKAT_MIN_NORM = 1e-9


def ray_length_to_z(ray: torch.Tensor, camera: PinholeCamera) -> torch.Tensor:
    """Euclidean distance along each pixel's ray -> z-depth: ``z = r / ||K^-1 (u, v, 1)||``.

    ray: (H, W) metres (0 = invalid stays 0); returns (H, W) of ``ray``'s dtype.
    """
    grid = pixel_grid(camera.height, camera.width, torch.float64)  # (H, W, 2)
    rays = unproject_jac_depth(grid, camera.params(torch.float64))  # (H, W, 3), unit z
    return (ray.double() / rays.norm(dim=-1)).to(ray.dtype)


def look_at_pose(
    eye: torch.Tensor, target: torch.Tensor, up: tuple[float, float, float] = SCENENET_UP
) -> torch.Tensor:
    """Camera-to-world ``T_wc`` (4, 4) float64 of a camera at ``eye`` (3,) looking at ``target`` (3,).

    OpenCV axes: z toward the target, x = z x up (right), y = z x x (down, i.e. against ``up``).
    Raises DatasetError when the direction is zero or parallel to ``up``.
    """
    eye = torch.as_tensor(eye, dtype=torch.float64)
    fwd = torch.as_tensor(target, dtype=torch.float64) - eye
    n = fwd.norm()
    if n < LOOKAT_MIN_NORM:
        raise DatasetError("look-at point coincides with the camera position")
    z = fwd / n
    x = torch.linalg.cross(z, torch.tensor(up, dtype=torch.float64))
    if x.norm() < LOOKAT_MIN_NORM:
        raise DatasetError("look-at direction is parallel to the world up direction")
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = torch.stack([x, y, z], dim=1)  # columns: camera axes in world coordinates
    T[:3, 3] = eye
    return T


def _vec(p) -> torch.Tensor:
    return torch.tensor([p.x, p.y, p.z], dtype=torch.float64)


def _find_trajectory(root: Path, protobuf: Path | None):
    """(trajectory message, protobuf path) for the folder ``root``."""
    parts = root.resolve().parts
    if protobuf is not None:
        candidates = [Path(protobuf)]
        if not candidates[0].is_file():
            raise DatasetError(f"SceneNet protobuf not found: {protobuf}")
    else:
        candidates = []
        for folder in (root, root.parent, root.parent.parent):
            candidates += sorted(folder.glob("*.pb"))
        if not candidates:
            raise DatasetError(
                f"no SceneNet protobuf (*.pb) in {root} or its two parent folders; pass its path"
            )
    for pb in candidates:
        trajs = read_trajectories(pb)
        for traj in trajs.trajectories:
            rp = Path(traj.render_path).parts
            if rp and tuple(parts[-len(rp):]) == tuple(rp):
                return traj, pb
    names = ", ".join(str(p) for p in candidates)
    raise DatasetError(f"no trajectory with a render_path naming {root} in {names}")


class SceneNetSequence(ImageFileSequence):
    """One SceneNet RGB-D trajectory folder (see the module docstring)."""

    format_name = "scenenet"

    def __init__(
        self, root: str | Path, protobuf: str | Path | None = None, camera: PinholeCamera | None = None
    ) -> None:
        super().__init__(root)
        if not self.root.is_dir():
            raise DatasetError(f"dataset folder not found: {self.root}")
        if not (self.root / "photo").is_dir():
            raise DatasetError(f"{self.root} is not a SceneNet trajectory folder: photo/ is missing")
        self._camera = SCENENET_CAMERA if camera is None else camera
        self.source_camera = self._camera
        traj, self.gt_path = _find_trajectory(self.root, None if protobuf is None else Path(protobuf))
        self._depth_dir = self.root / "depth"
        has_depth = self._depth_dir.is_dir()
        stamps, poses, photos, depths = [], [], [], []
        for k, view in enumerate(traj.views):
            where = f"{self.gt_path}: view {k} of trajectory {traj.render_path!r}"
            if not (view.HasField("frame_num") and view.HasField("shutter_open") and view.HasField("shutter_close")):
                raise DatasetError(f"{where} lacks frame_num, shutter_open or shutter_close")
            o, c = view.shutter_open, view.shutter_close
            t = 0.5 * (o.timestamp + c.timestamp)
            if not math.isfinite(t):
                raise DatasetError(f"{where}: non-finite timestamp")
            if stamps and t <= stamps[-1]:
                raise DatasetError(f"{where}: timestamp {t} is not after the previous one ({stamps[-1]})")
            eye = 0.5 * (_vec(o.camera) + _vec(c.camera))  # shutter midpoint, like the SceneNet scripts
            target = 0.5 * (_vec(o.lookat) + _vec(c.lookat))
            if not bool(torch.isfinite(eye).all() and torch.isfinite(target).all()):
                raise DatasetError(f"{where}: non-finite camera or look-at position")
            try:
                poses.append(look_at_pose(eye, target))
            except DatasetError as e:
                raise DatasetError(f"{where}: {e}") from None
            stamps.append(t)
            photos.append(require_file(self.root / "photo" / f"{view.frame_num}.jpg", where))
            if has_depth:
                depths.append(require_file(self._depth_dir / f"{view.frame_num}.png", where))
        if not stamps:
            raise DatasetError(f"trajectory {traj.render_path!r} in {self.gt_path} has no views")
        self._stamps = np.array(stamps, dtype=np.float64)
        self._gt = torch.stack(poses)  # (N, 4, 4)
        self._images = photos
        self._depths = depths if has_depth else None
        self.render_path = traj.render_path

    @staticmethod
    def detect(root: Path) -> bool:
        root = Path(root)
        return (root / "photo").is_dir() and (root / "depth").is_dir()

    def _read_depth(self, path: Path) -> torch.Tensor:
        ray = read_depth_png(path, SCENENET_DEPTH_FACTOR)  # each pixel's ray length, metres
        check_depth_shape(self._camera, ray, path)  # before the conversion, which needs the camera's size
        return ray_length_to_z(ray, self._camera)
