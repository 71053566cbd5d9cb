"""Pair selection: master pairs (Table 1), all pairs, overlap under a pose guess."""

from __future__ import annotations

import pytest
import torch

from codeslam.errors import CodeSLAMError
from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.lie import se3_exp
from codeslam.sfm.pairs import all_pairs, master_pairs, overlapping_pairs, view_overlap


def test_master_pairs():
    assert master_pairs(3, 1) == [(1, 0), (0, 1), (1, 2), (2, 1)]
    assert master_pairs(3, 0, both_directions=False) == [(0, 1), (0, 2)]
    with pytest.raises(CodeSLAMError):
        master_pairs(3, 3)


def test_all_pairs():
    assert all_pairs(3, both_directions=False) == [(0, 1), (0, 2), (1, 2)]
    assert len(all_pairs(4)) == 12 and all(a != b for a, b in all_pairs(4))


def test_overlap_falls_with_motion():
    cam = canonical_camera(64, 48)
    xi = torch.zeros(4, 6, dtype=torch.float64)
    xi[1, 0] = 0.2  # 20 cm sideways
    xi[2, 4] = 0.5  # turned 29 degrees
    xi[3, 4] = 2.0  # turned away
    poses = se3_exp(xi)
    ov = view_overlap(poses, cam, depth=3.0, step=4)
    torch.testing.assert_close(ov.diagonal(), torch.ones(4, dtype=torch.float64))
    assert 0.75 < ov[0, 1] < 0.95  # 20 cm at 3 m: about 7 of 64 pixels shift
    assert ov[0, 2] < ov[0, 1] and ov[0, 3] == 0
    pairs = overlapping_pairs(poses, cam, depth=3.0, min_overlap=0.5, step=4)
    assert (0, 1) in pairs and (1, 0) in pairs and (0, 3) not in pairs and (3, 0) not in pairs
