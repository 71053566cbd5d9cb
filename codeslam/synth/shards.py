"""Training shards: many random views of many synthetic rooms, in safetensors files.

Shard ``OUT/shard_%05d.safetensors`` holds M views:

- ``image``: (M, 3, H, W) uint8 RGB;
- ``depth``: (M, H, W) uint16 z-depth in units of 1/5000 m (0 = invalid);
- ``T_wc``: (M, 4, 4) float64 camera-to-world poses (each scene has its own world frame);

and string metadata ``camera`` (JSON of :meth:`PinholeCamera.to_dict`), ``depth_factor`` ("5000"), ``seed``,
``format`` ("codeslam-shard-v1"), ``shard``, ``views``, ``views_per_scene``, ``render`` (JSON of the
render settings).

Views come in groups of ``views_per_scene`` per room, so building a room (and its culling data) is shared.
A shard's content depends only on (seed, shard index, settings): shards are independent, a run can be
resumed (complete shards are skipped; files are written atomically so a shard on disk is complete) and
split across worker processes with identical results.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from codeslam.errors import CodeSLAMError, DatasetError
from codeslam.geometry.camera import PinholeCamera
from codeslam.io import atomic_path, ensure_dir
from codeslam.synth.motion import preset_path_views
from codeslam.synth.render import RenderConfig, depth_to_uint16, render, to_uint8
from codeslam.synth.scene import build_scene, build_scene_v2
from codeslam.synth.trajectory import random_views, random_views_v2, random_views_v3

SHARD_FORMAT = "codeslam-shard-v1"


def _rooms_and_views(make_scene, make_views):
    """A data version's ``draw(seed, n, rng) -> (scene, (n, 4, 4) T_wc)`` from its room and view functions."""

    def draw(seed: int, n: int, rng: np.random.Generator):
        scene = make_scene(seed)
        return scene, make_views(scene, n, rng)

    return draw


#: Data versions: how rooms are built and views drawn. 1: furnished rooms of 3-7 m seen mostly from close by
#: (the data of the first default weights); 2: also large rooms, open-plan spaces split into rooms, corridors,
#: ceilings to 4 m, and half the views looking along the room from standing or sitting height
#: (:func:`codeslam.synth.scene.build_scene_v2`, :func:`codeslam.synth.trajectory.random_views_v2`); 3: version
#: 2's rooms, 40% of the views along the room, 45% looking at furniture, tables, walls or the floor from a person's
#: height 0.7-4 m away, 15% version 1's close-ups (:func:`codeslam.synth.trajectory.random_views_v3`): version 2
#: kept version 1's table-top close-ups from 0.35-1.3 m for half its views, and a network trained on it still
#: took a person's downward view of a table 1.5-2.5 m away (the HoloLens walk) for such a close-up.
#: 4: rooms and views of the motion presets, each room walked through as one preset does and its views frames of
#: that path (:func:`codeslam.synth.motion.preset_path_views`): rooms of 4-15 m and 10-20 m corridors seen as people
#: moving a camera see them.
DATA_VERSIONS = {1: _rooms_and_views(build_scene, random_views), 2: _rooms_and_views(build_scene_v2, random_views_v2),
                 3: _rooms_and_views(build_scene_v2, random_views_v3), 4: preset_path_views}
#: Depth range (metres) for data versions 2 and up, whose rooms reach 20 m: the 16-bit depth's limit at 1/5000 m.
V2_MAX_DEPTH = 13.0
DEPTH_FACTOR = 5000.0
#: Views rendered in one call (bounds memory; results do not depend on it).
RENDER_BATCH = 8


@dataclass
class ShardSpec:
    """What a set of training shards holds (everything a shard's content depends on).

    Attributes:
        views: total number of views over all shards.
        camera: the pinhole camera of every view.
        seed: base seed; shard i's rooms and views come from (seed, i).
        views_per_scene: views rendered per random room.
        shard_size: views per shard (the last shard may hold fewer).
        render: shading and sensor settings.
        version: data version (:data:`DATA_VERSIONS`); 1 is what every shard was before versions existed.
    """

    views: int
    camera: PinholeCamera
    seed: int = 0
    views_per_scene: int = 16
    shard_size: int = 256
    render: RenderConfig = field(default_factory=RenderConfig)
    version: int = 1

    def __post_init__(self) -> None:
        if self.version not in DATA_VERSIONS:
            raise CodeSLAMError(f"--data-version must be one of {', '.join(map(str, DATA_VERSIONS))}, "
                                f"got {self.version}")
        if self.views < 1:
            raise CodeSLAMError(f"--views must be at least 1, got {self.views}")
        if self.views_per_scene < 1:
            raise CodeSLAMError(f"--views-per-scene must be at least 1, got {self.views_per_scene}")
        if self.shard_size < 1:
            raise CodeSLAMError(f"--shard-size must be at least 1, got {self.shard_size}")

    @property
    def num_shards(self) -> int:
        return math.ceil(self.views / self.shard_size)

    def shard_views(self, index: int) -> int:
        return min(self.shard_size, self.views - index * self.shard_size)


def shard_path(out_dir: str | Path, index: int) -> Path:
    return Path(out_dir) / f"shard_{index:05d}.safetensors"


def _scene_seed(seed: int, shard: int, scene: int) -> int:
    """A 63-bit seed for room ``scene`` of shard ``shard`` (independent streams via SeedSequence)."""
    return int(np.random.SeedSequence([seed, shard, scene, 0x7EA1]).generate_state(2, np.uint32).astype(
        np.uint64).dot([1 << 31, 1]))


def render_shard(spec: ShardSpec, index: int) -> dict[str, torch.Tensor]:
    """Render shard ``index``: {"image": (M, 3, H, W) uint8, "depth": (M, H, W) uint16, "T_wc": (M, 4, 4)}."""
    m = spec.shard_views(index)
    images, depths, poses = [], [], []
    scene_i = done = 0
    draw = DATA_VERSIONS[spec.version]
    while done < m:
        k = min(spec.views_per_scene, m - done)
        s_seed = _scene_seed(spec.seed, index, scene_i)
        rng = np.random.default_rng(np.random.SeedSequence([s_seed, 0x71E3]))
        scene, T = draw(s_seed, k, rng)
        for a in range(0, k, RENDER_BATCH):
            img, dep = render(scene, spec.camera, T[a:a + RENDER_BATCH], spec.render,
                              noise_seed=s_seed + a)
            images.append(to_uint8(img))
            depths.append(depth_to_uint16(dep, DEPTH_FACTOR))
        poses.append(T)
        done += k
        scene_i += 1
    return {"image": torch.cat(images), "depth": torch.cat(depths), "T_wc": torch.cat(poses)}


def _metadata(spec: ShardSpec, index: int) -> dict[str, str]:
    return {
        "format": SHARD_FORMAT,
        "camera": json.dumps(spec.camera.to_dict()),
        "depth_factor": str(int(DEPTH_FACTOR)),
        "seed": str(spec.seed),
        "shard": str(index),
        "views": str(spec.shard_views(index)),
        "views_per_scene": str(spec.views_per_scene),
        "render": json.dumps(asdict(spec.render), sort_keys=True),
    } | ({} if spec.version == 1 else {"data_version": str(spec.version)})


def write_shard(spec: ShardSpec, out_dir: str | Path, index: int) -> Path:
    """Render and atomically write shard ``index``; returns its path."""
    from safetensors.torch import save_file

    tensors = render_shard(spec, index)
    path = shard_path(out_dir, index)
    with atomic_path(path) as tmp:
        save_file({k: v.contiguous() for k, v in tensors.items()}, str(tmp), metadata=_metadata(spec, index))
        _canonicalise_header(tmp)
    return path


def _canonicalise_header(path: Path) -> None:
    """Rewrite a safetensors file's JSON header with sorted keys, in place.

    safetensors serialises its header from hash maps whose order changes from process to process, so two
    identical shards would differ byte for byte; sorting the keys (same length, same offsets) makes the file
    a function of its content only."""
    with open(path, "r+b") as f:
        n = int.from_bytes(f.read(8), "little")
        header = json.loads(f.read(n))
        text = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
        if len(text) > n:  # cannot happen for the same content; keep the library's file rather than break it
            return
        f.seek(8)
        f.write(text + b" " * (n - len(text)))


def shard_is_complete(spec: ShardSpec, out_dir: str | Path, index: int) -> bool:
    """Whether shard ``index`` exists with the metadata ``spec`` would write (same seed, camera, settings)."""
    path = shard_path(out_dir, index)
    if not path.is_file():
        return False
    try:
        from safetensors import safe_open

        with safe_open(str(path), "pt") as f:
            return f.metadata() == _metadata(spec, index)
    except Exception:  # an unreadable file is simply redone  # noqa: BLE001
        return False


def worker_init() -> None:
    """Initializer of worker processes: one torch thread each (parallelism comes from the processes; the
    renderer's tensors are cache-sized chunks, too small to gain from intra-op threads)."""
    torch.set_num_threads(1)


def _worker_write(args) -> tuple[int, float]:
    spec, out_dir, index = args
    t0 = time.perf_counter()
    write_shard(spec, out_dir, index)
    return index, time.perf_counter() - t0


def write_shards(spec: ShardSpec, out_dir: str | Path, workers: int = 1, progress=None) -> dict:
    """Write every missing shard of ``spec`` under ``out_dir`` (resumable).

    ``workers > 1`` renders shards in that many processes (one torch thread each). ``progress`` is called
    as ``progress(done, total)`` after each shard. Returns a summary dict (shards, views, written, skipped,
    seconds, views_per_second, paths).
    """
    out_dir = ensure_dir(out_dir)
    todo = [i for i in range(spec.num_shards) if not shard_is_complete(spec, out_dir, i)]
    t0 = time.perf_counter()
    done = spec.num_shards - len(todo)
    if workers <= 1:
        for i in todo:
            write_shard(spec, out_dir, i)
            done += 1
            if progress:
                progress(done, spec.num_shards)
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=worker_init) as pool:
            for _ in pool.map(_worker_write, [(spec, out_dir, i) for i in todo]):
                done += 1
                if progress:
                    progress(done, spec.num_shards)
    seconds = time.perf_counter() - t0
    rendered = sum(spec.shard_views(i) for i in todo)
    return {
        "shards": spec.num_shards,
        "views": spec.views,
        "written": len(todo),
        "skipped": spec.num_shards - len(todo),
        "seconds": seconds,
        "views_per_second": rendered / seconds if seconds > 0 and rendered else 0.0,
        "size": [spec.camera.width, spec.camera.height],
        "paths": [str(shard_path(out_dir, i)) for i in range(spec.num_shards)],
    }


def read_shard(path: str | Path) -> tuple[torch.Tensor, torch.Tensor, PinholeCamera]:
    """Read a training shard: image (M, 3, H, W) uint8, depth (M, H, W) float32 metres (0 = invalid) and
    the camera. Raises DatasetError for a missing, corrupt or foreign file."""
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"shard not found: {path}")
    try:
        with safe_open(str(path), "pt") as f:
            meta = f.metadata() or {}
            if meta.get("format") != SHARD_FORMAT:
                raise DatasetError(f"{path} is not a codeslam training shard (format {meta.get('format')!r})")
            image = f.get_tensor("image")
            depth_raw = f.get_tensor("depth")
    except (SafetensorError, OSError, ValueError) as e:
        raise DatasetError(f"cannot read shard {path}: {e}") from None
    try:
        cam = json.loads(meta["camera"])
        camera = PinholeCamera(cam["fx"], cam["fy"], cam["cx"], cam["cy"], int(cam["width"]), int(cam["height"]),
                               tuple(cam.get("dist", (0.0,) * 5)))
        factor = float(meta["depth_factor"])
    except (KeyError, ValueError, TypeError, CodeSLAMError) as e:
        raise DatasetError(f"shard {path} has malformed metadata: {e}") from None
    if not (math.isfinite(factor) and factor > 0):
        raise DatasetError(f"shard {path} has malformed metadata: depth_factor must be positive, got {factor}")
    if image.dtype != torch.uint8 or image.ndim != 4 or image.shape[1] != 3:
        raise DatasetError(f"shard {path}: image must be (M, 3, H, W) uint8, got {tuple(image.shape)} {image.dtype}")
    if depth_raw.shape != (image.shape[0],) + tuple(image.shape[2:]):
        raise DatasetError(f"shard {path}: depth shape {tuple(depth_raw.shape)} does not match the images")
    if (camera.width, camera.height) != (image.shape[3], image.shape[2]):
        raise DatasetError(f"shard {path}: images are {image.shape[3]}x{image.shape[2]} but its camera is "
                           f"{camera.width}x{camera.height}")
    depth = depth_raw.to(torch.int32).to(torch.float32) / factor
    return image, depth, camera
