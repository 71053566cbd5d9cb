"""``scripts/keyframe_errors.py``: each keyframe's tracked pose and its final one, in the keyframe it was tracked
against, read against the truth."""

from __future__ import annotations

import numpy as np
import pytest

from codeslam.data.trajectory import Trajectory


def _pose(axis: int, deg: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    T = np.eye(4)
    T[i, i], T[i, j], T[j, i], T[j, j] = c, -s, s, c
    T[:3, 3] = t
    return T


def test_tracked_and_final_errors_are_read_in_each_keyframes_reference(script):
    ke = script("keyframe_errors")
    stamps = np.array([0.0, 0.1, 0.2, 0.3])
    truth = np.stack([_pose(1, 5.0 * i, (0.2 * i, 0.0, 0.05 * i)) for i in range(4)])
    ref = Trajectory(stamps, truth)
    final = truth.copy()
    final[2] = truth[2] @ _pose(1, 2.0)  # the map turns keyframe 2 by 2 deg about its own centre
    rel1 = np.linalg.inv(truth[0]) @ truth[1]
    rel2 = np.linalg.inv(truth[1]) @ truth[2]
    tracked1 = rel1 @ _pose(0, 3.0)  # the tracker turned keyframe 1 by 3 deg in keyframe 0
    tracked2 = rel2.copy()
    tracked2[:3, 3] = _pose(1, 10.0)[:3, :3] @ rel2[:3, 3]  # and sent keyframe 2 10 deg off its direction (xz)
    kf = {
        "id": np.array([0, 1, 2, 3]), "frame_index": np.array([0, 1, 2, 3]), "timestamp": stamps, "T_wc": final,
        "tracked_from": np.array([-1, 0, 1, 9]),  # keyframe 3's reference is not in the file: left out
        "T_tracked": np.stack([np.full((4, 4), np.nan), tracked1, tracked2, np.eye(4)]),
    }
    out = ke.tracked_errors(kf, ref)
    np.testing.assert_array_equal(out["frame"], [1, 2])
    np.testing.assert_array_equal(out["reference"], [0, 1])
    np.testing.assert_allclose(out["tracked_rotation"], [3.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(out["final_rotation"], [0.0, 2.0], atol=1e-6)
    np.testing.assert_allclose(out["tracked_direction"], [0.0, 10.0], atol=1e-5)
    np.testing.assert_allclose(out["final_direction"], [0.0, 0.0], atol=1e-5)


def test_a_file_without_tracked_poses_is_said_so(script, capsys):
    ke = script("keyframe_errors")
    ref = Trajectory(np.array([0.0, 0.1]), np.stack([np.eye(4)] * 2))
    assert ke.tracked_errors({"id": np.array([0, 1])}, ref) is None
    assert "holds no tracked poses" in capsys.readouterr().out
    assert ke.direction_angle(np.zeros((1, 3)), np.ones((1, 3))) == pytest.approx(np.array([np.nan]), nan_ok=True)
