"""EuRoC MAV / ASL folders (Burri et al., IJRR 2016): monocular grey images with ground-truth poses.

Layout (``root`` is the sequence folder holding ``mav0/``, or ``mav0/`` itself)::

    mav0/cam0/data.csv                          #timestamp [ns],filename
    mav0/cam0/data/<timestamp>.png              8-bit grey, 752x480
    mav0/cam0/sensor.yaml                       intrinsics [fu, fv, cu, cv], resolution [w, h],
                                                distortion_coefficients [k1, k2, p1, p2] (radial-tangential),
                                                T_BS {rows: 4, cols: 4, data: [16 numbers]} sensor-to-body
    mav0/state_groundtruth_estimate0/data.csv   body (IMU) poses T_wb, see codeslam.data.euroc_csv

Grey images become three equal channels. There is no depth. The ground truth describes the *body* (IMU)
frame; the camera's pose is ``T_wc = T_wb @ T_BS`` (T_BS maps camera points into the body frame), with
``T_wb`` interpolated to the image timestamp first. Timestamps are nanoseconds in the files and seconds
here. Images are undistorted to the pinhole camera unless ``undistort=False`` (then the distortion
coefficients are ignored).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import yaml

from codeslam.data.base import ImageFileSequence
from codeslam.data.euroc_csv import NS_PER_S, read_euroc_csv
from codeslam.data.folder import yaml_error_text
from codeslam.data.imageio import require_file, resolve_in_root
from codeslam.data.textfile import check_increasing, data_lines
from codeslam.errors import CodeSLAMError, DatasetError
from codeslam.geometry.camera import PinholeCamera

#: Largest spacing of the two ground-truth samples a frame's pose is interpolated between (the estimate
#: runs at 200 Hz).
EUROC_GT_MAX_GAP_S = 0.05
#: Tolerance on ``R^T R = I`` for the rotation block of T_BS (the file stores it to ~12 digits).
T_BS_ORTHONORMAL_TOL = 1e-4


def mav_folder(root: Path) -> Path:
    """``root/mav0`` when it exists, else ``root`` (the user pointed at mav0 itself)."""
    return root / "mav0" if (root / "mav0").is_dir() else root


def read_cam_csv(path: Path, data_dir: Path) -> tuple[np.ndarray, list[Path]]:
    """``timestamp[ns],filename`` lines -> ((N,) float64 seconds, N image paths inside ``data_dir``)."""
    stamps_ns: list[int] = []
    files: list[Path] = []
    for where, line in data_lines(path):
        parts = [p.strip() for p in line.split(",")]
        if len(parts) != 2:
            raise DatasetError(f"{where}: expected 'timestamp[ns],filename', got {len(parts)} fields")
        try:
            ns = int(parts[0])
        except ValueError:
            raise DatasetError(f"{where}: timestamp {parts[0]!r} is not an integer (nanoseconds)") from None
        check_increasing(stamps_ns, ns, where, parts[0])
        files.append(require_file(resolve_in_root(data_dir, parts[1], where), where))
        stamps_ns.append(ns)
    # int / int true division is correctly rounded (float(ns) / 1e9 is not).
    return np.array([ns / NS_PER_S for ns in stamps_ns], dtype=np.float64), files


def _number_list(d: dict, key: str, n: int, path: Path) -> list[float]:
    val = d.get(key)
    if not isinstance(val, list) or len(val) != n:
        raise DatasetError(f"{path}: '{key}' must be a list of {n} numbers, got {val!r}")
    try:
        out = [float(v) for v in val]
    except (TypeError, ValueError):
        raise DatasetError(f"{path}: '{key}' must be a list of {n} numbers, got {val!r}") from None
    if not all(np.isfinite(out)):
        raise DatasetError(f"{path}: '{key}' holds a non-finite value")
    return out


def read_sensor_yaml(path: Path) -> tuple[PinholeCamera, torch.Tensor]:
    """EuRoC ``sensor.yaml`` -> (camera with distortion, T_BS (4, 4) float64 sensor-to-body)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"cannot read {path}: {e}") from None
    # OpenCV-written YAML starts with a "%YAML:1.0" directive that PyYAML rejects; it carries nothing.
    if text.startswith("%YAML:"):
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise DatasetError(f"{path} is not valid YAML: {yaml_error_text(e)}") from None
    if not isinstance(d, dict):
        raise DatasetError(f"{path} must hold a YAML mapping of camera parameters")
    model = d.get("camera_model", "pinhole")
    if model != "pinhole":
        raise DatasetError(f"{path}: camera_model {model!r} is not supported (only 'pinhole')")
    dist_model = d.get("distortion_model", "radial-tangential")
    if dist_model not in ("radial-tangential", "radtan"):
        raise DatasetError(f"{path}: distortion_model {dist_model!r} is not supported (only 'radial-tangential')")
    fu, fv, cu, cv = _number_list(d, "intrinsics", 4, path)
    w, h = _number_list(d, "resolution", 2, path)
    if w != int(w) or h != int(h):
        raise DatasetError(f"{path}: resolution must be two integers, got {[w, h]}")
    k = [0.0, 0.0, 0.0, 0.0]
    if "distortion_coefficients" in d:  # [k1, k2, p1, p2], or with k3
        dist = d["distortion_coefficients"]
        k = _number_list(d, "distortion_coefficients", 5 if isinstance(dist, list) and len(dist) == 5 else 4, path)
    try:
        camera = PinholeCamera(fu, fv, cu, cv, int(w), int(h), tuple(k) + (0.0,) * (5 - len(k)))
    except CodeSLAMError as e:
        raise DatasetError(f"{path}: {e}") from None
    tbs = d.get("T_BS")
    if not isinstance(tbs, dict):
        raise DatasetError(f"{path}: 'T_BS' must be a mapping with rows, cols and data")
    if tbs.get("rows") != 4 or tbs.get("cols") != 4:
        raise DatasetError(f"{path}: 'T_BS' must be 4x4, got rows={tbs.get('rows')} cols={tbs.get('cols')}")
    T_BS = torch.tensor(_number_list(tbs, "data", 16, path), dtype=torch.float64).reshape(4, 4)
    R = T_BS[:3, :3]
    if (R.T @ R - torch.eye(3, dtype=torch.float64)).abs().max() > T_BS_ORTHONORMAL_TOL or float(
        torch.linalg.det(R)
    ) < 0 or not torch.equal(T_BS[3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)):
        raise DatasetError(f"{path}: 'T_BS' is not a rigid transformation")
    return camera, T_BS


class EurocSequence(ImageFileSequence):
    """One camera of an EuRoC MAV sequence (``cam0`` by default)."""

    format_name = "euroc"

    def __init__(
        self,
        root: str | Path,
        cam: str = "cam0",
        undistort: bool = True,
        gt_max_gap: float = EUROC_GT_MAX_GAP_S,
    ) -> None:
        super().__init__(root)
        if not self.root.is_dir():
            raise DatasetError(f"dataset folder not found: {self.root}")
        mav = mav_folder(self.root)
        cam_dir = mav / cam
        csv = cam_dir / "data.csv"
        if not csv.is_file():
            raise DatasetError(f"{self.root} is not an EuRoC folder: {csv} is missing")
        sensor = cam_dir / "sensor.yaml"
        if not sensor.is_file():
            raise DatasetError(f"EuRoC camera calibration not found: {sensor}")
        self._stamps, self._images = read_cam_csv(csv, cam_dir / "data")
        if len(self._stamps) == 0:
            raise DatasetError(f"{csv} lists no images")
        camera, self.T_BS = read_sensor_yaml(sensor)
        self.source_camera = camera
        self.undistort = undistort and camera.has_distortion
        self._camera = camera.without_distortion()

        T_wb = self._read_gt(mav / "state_groundtruth_estimate0" / "data.csv", read_euroc_csv, self._stamps,
                             gt_max_gap, "image")  # (N, 4, 4)
        self._gt = None if T_wb is None else T_wb @ self.T_BS  # T_wc = T_wb T_bc (NaN rows stay NaN)

    @staticmethod
    def detect(root: Path) -> bool:
        root = Path(root)
        return (root / "mav0" / "cam0" / "data.csv").is_file() or (
            root.name == "mav0" and (root / "cam0" / "data.csv").is_file()
        )

