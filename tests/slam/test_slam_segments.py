"""Map segments merged when the camera comes back to a place an older segment mapped (codeslam.slam.segments)."""

from __future__ import annotations

import dataclasses
import math

import torch
from slam_scene import MemorySequence, preset_frames

from codeslam.geometry.lie import se3_exp, se3_inverse, so3_angle_host
from codeslam.sfm.variables import CODE, POSE, BlockId, LinearPrior, SfMState
from codeslam.slam.config import RecoveryConfig, SLAMConfig
from codeslam.slam.depth import standin_depth_model
from codeslam.slam.segments import SegmentMaps, motions_agree, segment_motion
from codeslam.slam.system import CodeSLAM

D = torch.float64


def test_a_segment_joins_the_map_of_the_segment_it_was_merged_into():
    maps = SegmentMaps()
    maps.join(2, 0)
    maps.join(3, 2)
    assert [maps.root(s) for s in range(4)] == [0, 1, 0, 0]
    try:
        maps.join(3, 0)
    except ValueError:
        pass
    else:
        raise AssertionError("segments of one map joined again")


def test_the_segment_motion_takes_the_frame_to_its_pose_in_the_older_map_and_agreement_reads_the_camera():
    g = torch.Generator().manual_seed(0)
    here, there = (se3_exp(torch.randn(6, generator=g, dtype=D)) for _ in range(2))
    G = segment_motion(here, there)
    assert torch.allclose(G @ here, there, atol=1e-12)
    nudge = se3_exp(torch.tensor([0.02, 0, 0, 0, 0, 0], dtype=D))  # 2 cm along x in the older map
    assert motions_agree(G, nudge @ G, here, depth=1.0, max_ratio=0.03, max_deg=1.0)
    assert not motions_agree(G, nudge @ G, here, depth=1.0, max_ratio=0.01, max_deg=1.0)
    turn = se3_exp(torch.tensor([0, 0, 0, 0, 0.05, 0], dtype=D))  # 2.9 deg
    assert not motions_agree(G, turn @ G, here, depth=1.0, max_ratio=10.0, max_deg=2.0)


def test_a_marginal_prior_moved_with_its_map_costs_what_it_cost_before():
    g = torch.Generator().manual_seed(1)
    blocks = [BlockId(POSE, 0), BlockId(CODE, 0), BlockId(POSE, 1)]
    A = torch.randn(16, 16, generator=g, dtype=D)
    x0 = [se3_exp(torch.randn(6, generator=g, dtype=D)), torch.randn(4, generator=g, dtype=D),
          se3_exp(torch.randn(6, generator=g, dtype=D))]
    prior = LinearPrior(blocks, A @ A.T, torch.randn(16, generator=g, dtype=D), x0)
    G = se3_exp(2.0 * torch.randn(6, generator=g, dtype=D))
    moved = prior.moved(G)
    for _ in range(3):
        poses = torch.stack([se3_exp(0.3 * torch.randn(6, generator=g, dtype=D)) @ x0[0],
                             se3_exp(0.3 * torch.randn(6, generator=g, dtype=D)) @ x0[2]])
        state = SfMState(poses, torch.randn(1, 4, generator=g, dtype=D), torch.zeros(0, 2, dtype=D))
        state_moved = SfMState(G @ poses, state.codes, state.affine)
        assert torch.allclose(moved.cost(state_moved), prior.cost(state), rtol=1e-10)
    # and not without the adjoint: the same H and b at the moved linearisation point cost something else
    naive = LinearPrior(blocks, prior.H, prior.b, moved.x0)
    assert not torch.allclose(naive.cost(state_moved), prior.cost(state), rtol=1e-3)


def _covered_walk_there_and_back():
    """The walk preset's frames 0-15, four blank frames (the lens covered while the camera is carried to frame 35's
    place), then frames 35 down to 0: (the preset's frames, the preset frame each frame shows or None, the
    sequence)."""
    frames = preset_frames(5, 36, "walk", 10.0)
    order = list(range(16)) + [None] * 4 + list(range(35, -1, -1))
    seq = MemorySequence([dataclasses.replace(frames[15 if j is None else j], timestamp=1000.0 + i / 10.0, index=i,
                                              image=torch.zeros_like(frames[0].image) if j is None
                                              else frames[j].image) for i, j in enumerate(order)])
    return frames, order, seq


def test_a_new_segment_is_merged_into_the_first_when_the_camera_comes_back_where_that_one_mapped():
    # The walk preset's frames 0-15, the lens covered for four frames while the camera is carried to frame 35's
    # place, then frames 35 down to 0: the camera walks back through what the first segment mapped. Relocalisation
    # is off, so the frame after the cover starts a new segment at the motion model's prediction, metres from the
    # truth; coming back, it is matched to the first segment's keyframes and moved into that map.
    frames, order, seq = _covered_walk_there_and_back()
    config = SLAMConfig(trajectory_smoothing=0.0, recovery=RecoveryConfig(relocalise=False))
    system = CodeSLAM(config, standin_depth_model(code_offset_scale=0.3))
    results = [system.process(f) for f in seq.frames]
    system.finish()
    assert max(r.segment for r in results) == 1, [r.segment for r in results]
    assert [(m.segment, m.into) for m in system.merges] == [(1, 0)]
    merged_at = next(i for i, r in enumerate(results) if "merged into segment 0" in r.reason)
    assert order[merged_at] is not None and order[merged_at] < 16  # where the first segment mapped
    poses = system.trajectory().poses
    start = next(i for i, r in enumerate(results) if r.segment == 1)
    # From the segment's first tracked frame on: here 0.15-0.22 m and 0.95-1.7 deg off; without the merge 1.5-1.7 m
    # and 24.5-25 deg.
    for i in range(start + 1, len(order)):
        T_true = se3_inverse(frames[0].pose) @ frames[order[i]].pose  # the world is frame 0's camera
        assert float((poses[i][:3, 3] - T_true[:3, 3]).norm()) < 0.4, (i, poses[i][:3, 3], T_true[:3, 3])
        assert math.degrees(so3_angle_host(T_true[:3, :3].T @ poses[i][:3, :3])) < 3.0, i


def test_a_frame_relocalised_in_an_older_map_starts_a_segment_of_that_map():
    # The walk and cover of the test above, merging off: the frame after the cover starts segment 1 at the motion
    # model's prediction. On the way back, at frame 8's place, the frame's tracking is made to fail and its
    # relocalisation may match only the first segment's keyframes, all outside the window: the map restarts there,
    # in segment 0's frame, so the frames from then on are a new segment of segment 0's map (not segment 1, whose
    # earlier frames lie metres away in a frame of their own).
    frames, order, seq = _covered_walk_there_and_back()
    config = SLAMConfig(trajectory_smoothing=0.0, recovery=RecoveryConfig(merge_segments=False))
    system = CodeSLAM(config, standin_depth_model(code_offset_scale=0.3))
    at = order.index(8, 16)
    track = system._track

    def failing_track(views, ref, T_kf_guess):
        out = track(views, ref, T_kf_guess)
        if views.frame.index == at:
            out = (dataclasses.replace(out[0], ok=False, reason="made to fail"), None, out[2])
        return out

    def first_segment_only(cands, frame, min_inliers):
        return relocalise([(k, kf) for k, kf in cands if system.keyframes[k].segment == 0], frame, min_inliers)

    system._track = failing_track
    results = []
    for f in seq.frames:
        if f.index == at:
            relocalise = system.sparse.relocalise
            system.sparse.relocalise = first_segment_only
        results.append(system.process(f))
        if f.index == at:
            system.sparse.relocalise = relocalise
    system.finish()
    assert results[at].status == "relocalised" and "segment 0's map" in results[at].reason, results[at].reason
    assert results[at - 1].segment == 1 and results[at].segment == 2
    assert system.maps.root(2) == 0 and system.maps.root(1) == 1
    assert {r.segment for r in results[at:]} == {2}
    poses = system.trajectory().poses
    for i in range(at, len(order)):  # in the first segment's frame (the world is frame 0's camera)
        T_true = se3_inverse(frames[0].pose) @ frames[order[i]].pose
        assert float((poses[i][:3, 3] - T_true[:3, 3]).norm()) < 0.4, (i, poses[i][:3, 3], T_true[:3, 3])
        assert math.degrees(so3_angle_host(T_true[:3, :3].T @ poses[i][:3, :3])) < 3.0, i
