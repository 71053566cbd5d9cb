"""Helpers of the bad-input corpus (issue 6): each writes one well-formed input into a tmp folder, which the
test then damages in one way, and :func:`assert_clean_failure` checks what every bad input must give:

* a non-zero exit code (2: the input's fault),
* exactly one line on stderr that starts with ``codeslam: error:`` (warnings may come before it),
* no ``Traceback`` anywhere and no ``internal error`` (a bug, not a user error),
* no partial or temporary files left in the output folder.

The writers are deliberately small (16x16 frames, a handful of them) so that the whole corpus runs in well
under a minute on a loaded 2-core machine.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from safetensors.torch import save_file

from codeslam.cli import main
from codeslam.data.imageio import write_depth_png, write_rgb_png
from codeslam.data.trajectory import Trajectory, write_tum
from codeslam.geometry.camera import canonical_camera
from codeslam.synth.shards import SHARD_FORMAT

W, H = 16, 16
T0 = 100.0
#: the tiny network of the network tests (tests/network/conftest.py), as YAML for ``--config``
TINY_NETWORK = dict(code_size=8, width=32, height=32, image_channels=[4, 8, 8, 8], depth_channels=[4, 8, 8, 8],
                    full_res_channels=4, bottleneck_channels=4, fc_units=16)
TINY_YAML = (
    "network:\n" + "".join(f"  {k}: {v}\n" for k, v in TINY_NETWORK.items())
    + "train:\n  batch_size: 2\n  log_every: 1\n  val_every: 100\n  checkpoint_every: 100\n  workers: 0\n"
)


# ---------------------------------------------------------------------------------------------- running


def run_cli(capsys, *args) -> tuple[int, str, str]:
    """Run ``codeslam ARGS`` in this process -> (exit code, stdout, stderr)."""
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def error_line(err: str) -> str:
    """The one error line of ``err`` (warnings allowed before it); fails the test if there is not exactly one."""
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("codeslam: warning:")]
    assert len(lines) == 1, f"expected one error line, got:\n{err}"
    assert lines[0].startswith("codeslam: error:"), err
    return lines[0]


def listing(folder: Path) -> set[str]:
    """Every path under ``folder`` (relative), empty when it does not exist."""
    if not folder.exists():
        return set()
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def assert_clean_failure(rc: int, err: str, *needles: str, out_dir: Path | None = None,
                         before: set[str] | None = None) -> str:
    """The bad-input contract (see the module docstring); ``needles`` must appear in the error line, and
    ``out_dir`` must hold exactly ``before`` (default: nothing) afterwards. Returns the error line."""
    assert rc == 2, f"exit code {rc}, stderr:\n{err}"
    assert "Traceback" not in err
    line = error_line(err)
    assert "internal error" not in line, line
    for needle in needles:
        assert needle in line, (needle, line)
    if out_dir is not None:
        left = listing(out_dir) - (before or set())
        assert not left, f"partial output left in {out_dir}: {sorted(left)}"
    return line


def temp_files(folder: Path) -> list[Path]:
    """Leftover temporaries of :mod:`codeslam.io` (``.NAME.*.tmp`` / ``.NAME.*.ext``) under ``folder``."""
    return [p for p in folder.rglob(".*") if p.is_file()]


# ---------------------------------------------------------------------------------------------- datasets


def _image(seed: int, w: int = W, h: int = H) -> torch.Tensor:
    return torch.rand(3, h, w, generator=torch.Generator().manual_seed(seed))


def _depth(seed: int, w: int = W, h: int = H) -> torch.Tensor:
    return 0.5 + 2.0 * torch.rand(h, w, generator=torch.Generator().manual_seed(1000 + seed))


def tum_folder(root: Path, n: int = 3, calib: str | None = "14 14 7.5 7.5", gt: bool = True) -> Path:
    """A TUM RGB-D folder of ``n`` 16x16 frames with depth, ground truth and calib.txt."""
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb, dep = ["# color images"], ["# depth maps"]
    for k in range(n):
        t = T0 + k / 30.0
        write_rgb_png(root / "rgb" / f"{t:.6f}.png", _image(k))
        write_depth_png(root / "depth" / f"{t:.6f}.png", _depth(k), 5000)
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        dep.append(f"{t:.6f} depth/{t:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(dep) + "\n")
    if calib is not None:
        (root / "calib.txt").write_text(calib + "\n")
    if gt:
        ts = T0 - 0.1 + np.arange(n * 4 + 20) * 0.01
        write_tum(root / "groundtruth.txt", Trajectory(ts, line_poses(len(ts))))
    return root


def tum_file(root: Path, kind: str, k: int) -> Path:
    """The file of frame ``k`` of ``kind`` ('rgb' or 'depth') of a :func:`tum_folder`."""
    return root / kind / f"{T0 + k / 30.0:.6f}.png"


def folder_dataset(root: Path, n: int = 2, yaml_text: str = "fx: 14\nfy: 14\ncx: 7.5\ncy: 7.5\n",
                   npy_depth: list[np.ndarray] | None = None) -> Path:
    """An image-folder dataset: images/000k.png, camera.yaml and optional .npy depth maps."""
    (root / "images").mkdir(parents=True)
    for k in range(n):
        write_rgb_png(root / "images" / f"frame_{k:04d}.png", _image(k))
    if npy_depth is not None:
        (root / "depth").mkdir()
        for k, d in enumerate(npy_depth):
            np.save(root / "depth" / f"frame_{k:04d}.npy", d)
    (root / "camera.yaml").write_text(yaml_text)
    return root


def tartanair_folder(root: Path, depths: list[np.ndarray]) -> Path:
    """A TartanAir sequence of len(depths) 640x480 frames (TartanAir's fixed camera) with the given depths."""
    (root / "image_left").mkdir(parents=True)
    (root / "depth_left").mkdir()
    for k, d in enumerate(depths):
        Image.fromarray(np.full((480, 640, 3), 40 * k + 20, np.uint8)).save(root / "image_left" / f"{k:06d}_left.png")
        np.save(root / "depth_left" / f"{k:06d}_left_depth.npy", d)
    return root


# ---------------------------------------------------------------------------------------------- trajectories


def line_poses(n: int, seed: int = 0) -> torch.Tensor:
    """(n, 4, 4) camera-to-world poses along a curved, turning path (not collinear: Umeyama has a solution)."""
    t = np.arange(n, dtype=np.float64) * 0.05
    T = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    c, s = np.cos(0.3 * t), np.sin(0.3 * t)
    T[:, 0, 0], T[:, 0, 2], T[:, 2, 0], T[:, 2, 2] = (torch.from_numpy(v) for v in (c, s, -s, c))
    T[:, :3, 3] = torch.from_numpy(np.stack([np.sin(t), 0.3 * t, np.cos(t) - 1 + 0.01 * seed], axis=1))
    return T


def trajectory_file(path: Path, stamps: np.ndarray, seed: int = 0) -> Path:
    write_tum(path, Trajectory(np.asarray(stamps, np.float64), line_poses(len(stamps), seed)))
    return path


# ---------------------------------------------------------------------------------------------- network files


def write_shard(path: Path, n: int = 6, size: int = 32, seed: int = 0) -> Path:
    """A training shard in the generator's format at the tiny network's canonical camera."""
    g = torch.Generator().manual_seed(seed)
    images = (torch.rand(n, 3, size, size, generator=g) * 255).to(torch.uint8)
    depth = ((1.0 + 2.0 * torch.rand(n, size, size, generator=g)) * 5000).round().to(torch.int32).to(torch.uint16)
    cam = canonical_camera(size, size)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_file({"image": images, "depth": depth}, str(path),
              metadata={"format": SHARD_FORMAT, "camera": json.dumps(cam.to_dict()), "depth_factor": "5000"})
    return path


def tiny_yaml(path: Path, extra: str = "") -> Path:
    path.write_text(TINY_YAML + extra)
    return path


def tiny_weights(path: Path, **overrides) -> Path:
    """Seeded weights of the tiny network (``overrides`` change its architecture) in codeslam's format."""
    from codeslam.network.config import NetworkConfig
    from codeslam.network.model import CodeNetwork
    from codeslam.network.weights import save_weights

    cfg = NetworkConfig(**{**TINY_NETWORK, **overrides})
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        model = CodeNetwork(cfg)
    save_weights(path, model)
    return path


class _Payload:
    """Unpickling this object calls ``Path.touch(marker)``: a harmless stand-in for code execution. If the
    marker exists after a command has read the file, the command unpickled it."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def pickle_payload(path: Path, marker: Path, protocol: int = pickle.HIGHEST_PROTOCOL) -> Path:
    """A pickle whose loading would create ``marker`` (wrapped in a dict, like a state dict)."""
    path.write_bytes(pickle.dumps({"state_dict": _Payload(marker), "code_size": 8}, protocol=protocol))
    return path


def torch_save_payload(path: Path, marker: Path) -> Path:
    """The same payload inside a ``torch.save`` zip archive (what a ``.pt`` / ``.pth`` checkpoint is)."""
    torch.save({"state_dict": _Payload(marker)}, path)
    return path


def yaml_payload(marker: Path) -> str:
    """YAML whose *unsafe* loading would create ``marker`` twice over (python/object tags calling
    ``builtins.open(marker, 'w')`` and ``os.system('touch marker')``); safe loading must refuse the tags."""
    return (f"network: !!python/object/apply:builtins.open ['{marker}', 'w']\n"
            f"train: !!python/object/apply:os.system ['touch {marker}']\n")
