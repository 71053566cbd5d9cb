"""The video reader: a sequence rendered by the generator and encoded to MP4 with PyAV decodes back to the rendered
frames with their timestamps; --fps / --every subsampling; forward, backward and seeking reads; the field-of-view
guess and calibration files; display rotation; one-line errors for bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from codeslam.data import video as video_module
from codeslam.data.registry import detect_format, open_dataset
from codeslam.data.video import VideoSequence, subsample_times, write_video
from codeslam.errors import ConfigError, DatasetError
from codeslam.geometry.camera import canonical_camera
from codeslam.synth.generate import generate_sequence

W, H, N, FPS = 64, 48, 16, 30
pytestmark = pytest.mark.filterwarnings("ignore:.*no calibration file")  # the default guess, checked once below


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """(the generator's frames as (H, W, 3) uint8, an MP4 of them at 30 frames per second)."""
    root = tmp_path_factory.mktemp("video")
    generate_sequence(root / "seq", seed=3, frames=N, camera=canonical_camera(W, H))
    images = [np.asarray(Image.open(p).convert("RGB")) for p in sorted((root / "seq" / "rgb").glob("*.png"))]
    return images, write_video(root / "room.mp4", images)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return 10 * math.log10(1.0 / float(np.mean((a - b) ** 2)))


def test_frames_decode_to_the_rendered_images_with_their_timestamps(rendered):
    images, path = rendered
    seq = open_dataset(path)
    assert seq.format_name == "video" and detect_format(path) == "video"
    assert len(seq) == N and not seq.has_depth and seq.gt_poses is None
    np.testing.assert_allclose(seq.timestamps, np.arange(N) / FPS, atol=1e-9)
    for i in range(N):
        frame = seq[i]
        assert frame.image.shape == (3, H, W) and frame.depth is None and frame.pose is None
        assert frame.timestamp == pytest.approx(i / FPS)
        # lossy, but each frame is its own rendered image, not a neighbour's
        own = _psnr(frame.image.permute(1, 2, 0).numpy(), images[i] / 255.0)
        assert own > 28, (i, own)
        if i + 1 < N:
            assert own > _psnr(frame.image.permute(1, 2, 0).numpy(), images[i + 1] / 255.0) + 3


def test_reading_backward_and_seeking_give_the_same_frames(rendered, monkeypatch):
    _, path = rendered
    forward = [f.image for f in VideoSequence(path)]
    seq = VideoSequence(path)
    for i in (10, 3, 15, 0, 7):  # backward jumps reopen the decoder
        assert bool((seq[i].image == forward[i]).all()), i
    monkeypatch.setattr(video_module, "SEEK_AHEAD_FRAMES", 2)  # far jumps seek to the key frame before
    seq = VideoSequence(path)
    for i in (12, 4, 9, 15):
        assert bool((seq[i].image == forward[i]).all()), i


def test_fps_and_every_subsample_the_frames(rendered):
    _, path = rendered
    seq = open_dataset(path, fps=10)
    np.testing.assert_allclose(seq.timestamps, [0.0, 0.1, 0.2, 0.3, 0.4, 0.5], atol=1e-9)
    assert bool((seq[1].image == VideoSequence(path)[3].image).all())
    assert len(open_dataset(path, every=4)) == 4
    np.testing.assert_allclose(open_dataset(path, fps=10, every=2).timestamps, [0.0, 0.2, 0.4], atol=1e-9)
    assert len(open_dataset(path, fps=100)) == N  # a higher rate than the video's keeps every frame


def test_subsampling_follows_time_not_frame_counts():
    t = np.arange(300) / 29.97 + np.random.default_rng(0).normal(scale=1e-4, size=300)  # NTSC rate, jitter
    keep = subsample_times(t, fps=10)
    assert len(keep) == pytest.approx(10 * t[-1], abs=1.5)
    assert np.all(np.diff(t[keep]) > 0.09) and np.all(np.diff(t[keep]) < 0.14)
    assert list(subsample_times(np.arange(10) / 30, every=3)) == [0, 3, 6, 9]
    for bad in ({"fps": 0}, {"fps": -5.0}, {"fps": math.nan}, {"every": 0}):
        with pytest.raises(ConfigError):
            subsample_times(t, **bad)


def test_camera_is_a_stated_guess_or_the_calibration(rendered, tmp_path):
    _, path = rendered
    seq = VideoSequence(path, fov=90)
    assert seq.camera.fx == pytest.approx((W / 2) / math.tan(math.radians(45)))
    assert seq.camera.cx == pytest.approx((W - 1) / 2) and "90 deg" in seq.camera_source
    assert seq.describe()["fov_guess_deg"] == 90
    with pytest.warns(UserWarning, match="no calibration file"):
        assert "60 deg" in VideoSequence(path).camera_source  # the default guess, stated
    cam = tmp_path / "camera.yaml"
    cam.write_text("fx: 50.0\nfy: 51.0\ncx: 31.0\ncy: 24.0\nwidth: 64\nheight: 48\n")
    seq = VideoSequence(path, camera=cam)
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cy) == (50.0, 51.0, 24.0)
    assert "calibration" in seq.camera_source and "fov_guess_deg" not in seq.describe()
    cam.write_text("fx: 50.0\nfy: 51.0\ncx: 31.0\ncy: 24.0\nwidth: 640\nheight: 480\n")
    with pytest.raises(ConfigError, match="640x480"):
        VideoSequence(path, camera=cam)
    cam.write_text("fx: fifty\nfy: 51.0\ncx: 31.0\ncy: 24.0\n")
    with pytest.raises(ConfigError, match="fx"):
        VideoSequence(path, camera=cam)
    with pytest.raises(ConfigError, match="not both"):
        VideoSequence(path, camera=cam, fov=60)
    for bad in (0, 180, -10, math.inf):
        with pytest.raises(ConfigError, match="--fov"):
            VideoSequence(path, fov=bad)


def test_display_rotation_turns_frames_as_a_player_does(tmp_path):
    img = np.zeros((H, W, 3), np.uint8)
    img[:8, :8] = 255  # a white block at the top left of the stored frame
    seq = VideoSequence(write_video(tmp_path / "portrait.mp4", [img] * 3, rotation=90))
    assert seq.rotation == 90 and (seq.camera.width, seq.camera.height) == (H, W)
    frame = seq[0].image.mean(0).numpy()  # (W, H): turned a quarter counter-clockwise
    assert frame.shape == (W, H)
    assert frame[-8:, :8].mean() > 0.8 and frame[:8, :8].mean() < 0.2  # the block is now at the bottom left
    # the sensor's rows (the stored frame's) are the turned frame's columns, for the rolling-shutter model
    assert seq[0].readout_axis == "columns"
    assert VideoSequence(write_video(tmp_path / "flipped.mp4", [img] * 3, rotation=180))[0].readout_axis == "rows"
    assert VideoSequence(write_video(tmp_path / "landscape.mp4", [img] * 3))[0].readout_axis == "rows"


def test_bad_videos_are_one_line_errors(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        open_dataset(tmp_path / "missing.mp4")
    fake = tmp_path / "fake.mp4"
    fake.write_text("not a video\n")
    with pytest.raises(DatasetError, match="cannot read video") as e:
        open_dataset(fake)
    assert "\n" not in str(e.value)
    text = tmp_path / "notes.txt"
    text.write_text("x")
    with pytest.raises(DatasetError, match="not a folder, nor a video file"):
        open_dataset(text)
