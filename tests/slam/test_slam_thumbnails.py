"""PTAM's small blurry images: what makes two views alike, and which keyframe a lost frame looks like."""

from __future__ import annotations

import torch
from slam_scene import preset_frames

from codeslam.slam.thumbnails import THUMBNAIL_SIZE, most_alike, thumbnail


def test_a_thumbnail_is_zero_mean_unit_norm_and_blind_to_exposure_and_colour_format():
    frame = preset_frames(5, 1, "walk", 10.0)[0]
    t = thumbnail(frame.image)
    assert t.shape == (THUMBNAIL_SIZE[0] * THUMBNAIL_SIZE[1],) and t.dtype == torch.float32
    assert abs(float(t.mean())) < 1e-6 and abs(float(t.norm()) - 1.0) < 1e-5
    darker = thumbnail(0.6 * frame.image + 0.05)  # a change of gain and offset
    assert float(darker @ t) > 0.9999
    grey = thumbnail(frame.gray)  # the same image as (1, H, W) grey, and as (H, W)
    assert torch.allclose(grey, t, atol=1e-5) and torch.allclose(thumbnail(frame.gray[0]), t, atol=1e-5)
    flat = thumbnail(torch.full((3, 96, 128), 0.4))
    assert float(flat.abs().max()) == 0.0  # a blank image is like nothing


def test_a_frame_looks_most_like_the_view_it_was_taken_near_not_the_others():
    frames = preset_frames(5, 44, "walk", 10.0)  # 3.3 m and 18 deg from frame 3 to frame 39
    stored = [0, 4, 10, 16, 22, 28, 34, 40]
    thumbs = torch.stack([thumbnail(frames[i].image) for i in stored])
    assert [stored[i] for i in most_alike(thumbnail(frames[3].image), thumbs, 2)] == [4, 0]
    assert [stored[i] for i in most_alike(thumbnail(frames[27].image), thumbs, 1)] == [28]
    assert most_alike(thumbnail(frames[3].image), thumbs[:0], 2) == []
    assert most_alike(thumbnail(frames[3].image), thumbs, 0) == []
    assert len(most_alike(thumbnail(frames[3].image), thumbs[:1], 3)) == 1
