"""A live 3D view of the SLAM system in the rerun viewer (https://rerun.io): the camera with its image, the
trajectory so far, and each keyframe's decoded depth as a coloured point cloud.

``rerun-sdk`` is an optional extra (``pip install 'codeslam[viewer]'``); it is imported when the viewer is
created, and its absence is reported as one clear error."""

from __future__ import annotations

import numpy as np

from codeslam.errors import CodeSLAMError
from codeslam.viz.base import Visualizer

#: Keyframe point clouds are subsampled by this stride per image axis (keeps the viewer responsive).
POINT_STRIDE = 2


def _import_rerun():
    try:
        import rerun
    except ImportError:
        raise CodeSLAMError(
            "the rerun viewer needs the optional rerun-sdk package: pip install 'codeslam[viewer]' "
            "(or use --viewer none)"
        ) from None
    return rerun


class RerunVisualizer(Visualizer):
    """Logs every frame to a rerun recording. spawn: start a viewer window (False: log to ``save_path`` or to
    whatever sink rerun is configured with)."""

    def __init__(self, app_id: str = "codeslam", spawn: bool = True, save_path: str | None = None) -> None:
        self.rr = _import_rerun()
        self.rr.init(app_id, spawn=spawn)
        if save_path is not None:
            self.rr.save(save_path)
        self.rr.log("world", self.rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, static=True)  # OpenCV axes
        self._positions: list[np.ndarray] = []
        self._logged_keyframes: set[int] = set()

    def _set_frame(self, index: int) -> None:
        rr = self.rr
        if hasattr(rr, "set_time"):  # rerun >= 0.23
            rr.set_time("frame", sequence=index)
        else:
            rr.set_time_sequence("frame", index)

    def _camera(self, path: str, T_wc: np.ndarray, camera) -> None:
        rr = self.rr
        rr.log(path, rr.Transform3D(translation=T_wc[:3, 3], mat3x3=T_wc[:3, :3]))
        rr.log(f"{path}/image", rr.Pinhole(focal_length=[camera.fx, camera.fy],
                                           principal_point=[camera.cx, camera.cy],
                                           width=camera.width, height=camera.height))

    def update(self, frame, result, system) -> None:
        rr = self.rr
        self._set_frame(result.index)
        T_wc = result.T_wc.numpy()
        self._camera("world/camera", T_wc, frame.camera)
        rgb = (frame.image.permute(1, 2, 0).clamp(0, 1).cpu().numpy() * 255).astype(np.uint8)  # (H, W, 3)
        rr.log("world/camera/image", rr.Image(rgb))
        self._positions.append(T_wc[:3, 3])
        rr.log("world/trajectory", rr.LineStrips3D([np.stack(self._positions)]))
        rr.log("status", rr.TextLog(f"frame {result.index}: {result.status} {result.reason}".strip()))
        if result.is_keyframe or result.window is not None:
            for kf in system.window.keyframes:  # the window moved: re-log its keyframes' clouds
                self._keyframe(kf)

    def _keyframe(self, kf) -> None:
        from codeslam.geometry.camera import pixel_grid, unproject

        rr = self.rr
        cam = kf.view.camera
        depth = kf.depth_map().detach().cpu().double()  # (H, W)
        uv = pixel_grid(cam.height, cam.width, depth.dtype)  # (H, W, 2)
        xyz_c = unproject(uv, depth, cam.params(depth.dtype))[::POINT_STRIDE, ::POINT_STRIDE].reshape(-1, 3)
        T = kf.T_wc.numpy()
        xyz_w = xyz_c.numpy() @ T[:3, :3].T + T[:3, 3]
        img = kf.view.image.detach().cpu()
        img = (img if img.dim() == 3 else img[None]).expand(3, -1, -1)  # (3, H, W), grey repeated
        rgb = img[:, ::POINT_STRIDE, ::POINT_STRIDE].reshape(3, -1).T.numpy()  # (N, 3)
        colors = (rgb.clip(0, 1) * 255).astype(np.uint8)
        rr.log(f"world/keyframes/{kf.id}/points", rr.Points3D(xyz_w, colors=colors, radii=0.005))
        self._camera(f"world/keyframes/{kf.id}/camera", T, cam)

    def close(self) -> None:
        if hasattr(self.rr, "disconnect"):
            self.rr.disconnect()
