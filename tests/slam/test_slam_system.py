"""The SLAM system end to end on a short synthetic sequence, and its handling of bad frames."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from slam_scene import MemorySequence, small_config, synth_frames

from codeslam.clock import StageClock
from codeslam.errors import CodeSLAMError
from codeslam.eval.slam_run import evaluate_run
from codeslam.geometry.camera import canonical_camera
from codeslam.slam.depth import standin_depth_model
from codeslam.slam.pipeline import ground_truth, run_slam
from codeslam.slam.system import CodeSLAM


@pytest.fixture(scope="module")
def run_and_gt():
    """16 frames at 64x48 through a room (0.57 m, 35 degrees), 3 keyframes per window so that keyframes get
    marginalised."""
    frames = synth_frames(3, 16, 7.5)
    seq = MemorySequence(frames)
    # the trajectory as the keyframes and tracking place it, without the written trajectory's smoothing spline
    # (tests/slam/test_slam_smoothing.py), so that each keyframe's frame sits at its keyframe's pose
    system = CodeSLAM(dataclasses.replace(small_config(size=3), trajectory_smoothing=0.0),
                      standin_depth_model(num_levels=3), clock=StageClock())
    sizes = []

    class _Watch:
        def update(self, frame, result, system):
            sizes.append(len(system.window))

        def close(self):
            pass

    run = run_slam(seq, system, frames[0].camera, visualizer=_Watch())
    return run, ground_truth(seq, range(len(seq))), sizes


def test_end_to_end_trajectory_beats_the_no_motion_baseline(run_and_gt):
    run, gt, _ = run_and_gt
    ev = evaluate_run(run.trajectory, gt)
    print(f"ATE se3 {ev['ate_se3_rmse']:.4f} m, sim3 {ev['ate_sim3_rmse']:.4f} m (scale {ev['sim3_scale']:.3f}); "
          f"no-motion {ev['no_motion_ate_rmse']:.4f} m, aligned {ev['no_motion_ate_rmse_aligned']:.4f} m; "
          f"rotation {ev['rot_err_rmse_deg']:.2f} deg; path {ev['path_length_gt']:.3f} m")
    assert all(r.tracking_ok for r in run.results)
    assert ev["ate_se3_rmse"] < 0.25 * ev["no_motion_ate_rmse_aligned"]
    assert ev["ate_sim3_rmse"] < 0.25 * ev["no_motion_ate_rmse_aligned"]
    assert 0.7 < ev["sim3_scale"] < 1.4  # the depth model's scale is metric; the map keeps it roughly


def test_keyframes_window_and_marginalisation(run_and_gt):
    run, _, sizes = run_and_gt
    res = run.results
    assert res[0].is_keyframe and res[0].status == "initialising" and res[0].keyframe_id == 0
    assert torch.equal(run.trajectory.poses[0], torch.eye(4, dtype=torch.float64))  # the map's origin
    kf_results = [r for r in res if r.is_keyframe]
    assert len(run.keyframes) == len(kf_results) >= 4
    assert max(sizes) == 3  # never more keyframes in the window than configured
    marginalised = [r.marginalised_id for r in res if r.marginalised_id is not None]
    assert marginalised == list(range(len(run.keyframes) - 3))  # the oldest, in order
    assert all(k.depth is not None and k.view.decoder is None for k in run.keyframes[:-3])
    assert all(r.status == "tracked" for r in res[res.index(kf_results[1]):])
    second = kf_results[1]
    assert second.window is not None and second.window.iterations > 0  # two-frame SfM initialisation
    assert {"track", "decode", "window"} <= set(second.timings_ms)
    # Every frame's final pose is its keyframe's final pose composed with its tracked relative pose.
    assert [k.frame_index for k in run.keyframes] == [r.index for r in kf_results]
    for k in run.keyframes:
        torch.testing.assert_close(run.trajectory.poses[k.frame_index], k.T_wc)


def test_a_corrupt_frame_is_flagged_and_the_system_continues():
    frames = synth_frames(3, 16, 10.0)[:6]
    bad = dataclasses.replace(frames[3], image=frames[3].image.clone())
    bad.image[:, 5:9, 5:9] = float("nan")
    frames[3] = bad
    system = CodeSLAM(small_config(), standin_depth_model(num_levels=3))
    results = [system.process(f) for f in frames]
    assert not results[3].tracking_ok and results[3].status == "predicted" and "non-finite" in results[3].reason
    assert bool(torch.isfinite(results[3].T_wc).all())
    assert all(r.tracking_ok for i, r in enumerate(results) if i != 3)
    assert system.tracking_failures() == [3]


def test_a_frame_that_cannot_anchor_the_map_waits_for_one_that_can():
    # A black first frame used to become the map's origin: the frames after it failed against it until a new
    # segment began (one black frame before TUM fr1/rpy: frames 1-4 lost). It is one lost frame now.
    frames = synth_frames(3, 16, 10.0)[:6]
    black = dataclasses.replace(frames[0], image=torch.zeros_like(frames[0].image))
    corrupt = dataclasses.replace(frames[1], image=frames[1].image.clone())
    corrupt.image[0, 0, 0] = float("inf")
    system = CodeSLAM(small_config(), standin_depth_model(num_levels=3))
    results = [system.process(f) for f in [black, corrupt, *frames[2:]]]
    assert [r.status for r in results[:2]] == ["predicted", "predicted"]
    assert "no texture" in results[0].reason and "non-finite" in results[1].reason
    assert results[2].is_keyframe and results[2].reason == "first frame" and results[2].keyframe_id == 0
    assert all(r.tracking_ok for r in results[3:])
    assert system.tracking_failures() == [0, 1]
    traj = system.trajectory()
    assert len(traj.timestamps) == 6 and bool(torch.isfinite(traj.poses).all())
    # before the map, a frame is placed at the origin its first keyframe has
    assert torch.allclose(traj.poses[0], system.keyframes[0].T_wc.to(traj.poses.dtype))
    # a sequence without a frame that can start a map is a user error, not a map anchored on nothing
    system = CodeSLAM(small_config(), standin_depth_model(num_levels=3))
    for f in frames[:3]:
        assert not system.process(dataclasses.replace(f, image=torch.full_like(f.image, 0.5))).tracking_ok
    with pytest.raises(CodeSLAMError, match="none of the 3 frames could start one .*no texture"):
        system.trajectory()


def test_a_blank_frame_in_mid_run_is_lost_without_touching_the_map():
    # A black frame used to be aligned, fail, make the frame before it a keyframe ("next frame lost") and undo the
    # last window solve, as a failure caused by the map would; it has nothing to align.
    frames = synth_frames(3, 16, 10.0)[:8]
    frames[5] = dataclasses.replace(frames[5], image=torch.zeros_like(frames[5].image))
    system = CodeSLAM(small_config(), standin_depth_model(num_levels=3))
    results = [system.process(f) for f in frames]
    assert results[5].status == "predicted" and results[5].reason.startswith("no texture in the frame")
    assert results[5].track is None and not results[5].rolled_back and not results[5].is_keyframe
    assert not any(r.reason == "next frame lost" for r in results)
    assert len(system.keyframes) == sum(r.is_keyframe for r in results)
    assert system.tracking_failures() == [5]


def test_bad_inputs_to_the_system_are_user_errors():
    frames = synth_frames(3, 16, 10.0)[:3]
    cfg = small_config()
    with pytest.raises(CodeSLAMError, match="pyramid levels"):
        CodeSLAM(cfg, standin_depth_model(num_levels=2)).process(frames[0])
    with pytest.raises(CodeSLAMError, match="depth maps"):
        CodeSLAM(cfg, standin_depth_model(num_levels=3)).process(dataclasses.replace(frames[0], depth=None))
    system = CodeSLAM(cfg, standin_depth_model(num_levels=3))
    system.process(frames[0])
    # A frame of another camera is resampled to the map's (the paper's intrinsics correction), not refused.
    other = system.process(dataclasses.replace(frames[1], camera=canonical_camera(64, 48, hfov_deg=70)))
    assert bool(torch.isfinite(other.T_wc).all())
    with pytest.raises(CodeSLAMError, match="timestamp"):
        system.process(dataclasses.replace(frames[1], timestamp=frames[0].timestamp))


def test_a_rolling_shutter_readout_rectifies_each_frame_by_the_motion_models_rotation():
    """tracker.rolling_shutter_readout: the frame the tracker sees is the input rectified by the readout times the
    last inter-frame rotation (none before two frames are tracked), its keypoints likewise; a frame that becomes a
    keyframe is rectified again with the rotation from the last frame to its tracked pose."""
    from codeslam.geometry.lie import se3_exp, se3_inverse, so3_log
    from codeslam.geometry.rolling_shutter import rectify_image, source_pixels

    frames = synth_frames(3, 4, 7.5)
    cfg = small_config(size=3)
    cfg = dataclasses.replace(cfg, tracker=dataclasses.replace(cfg.tracker, rolling_shutter_readout=0.5,
                                                                rolling_shutter_estimate=False))
    system = CodeSLAM(cfg, standin_depth_model(num_levels=3))
    system.camera = frames[0].camera
    assert system._last_motion() is None and system._readout_rotation(None, 0.1) is None
    for f in frames[:3]:
        system.process(f)
    T = se3_inverse(system._pose(system._records[-2])) @ system._pose(system._records[-1])
    omega = system._readout_rotation(*system._last_motion())
    assert torch.allclose(omega, 0.5 * so3_log(T[:3, :3]), atol=1e-12) and float(omega.norm()) > 1e-3
    views = system._views(frames[3])
    expected, _ = rectify_image(frames[3].image, source_pixels(frames[3].camera, frames[3].camera, omega))
    assert torch.allclose(views.frame.image, expected, atol=1e-6)
    # a new keyframe is rectified again with the rotation from the last frame to its tracked pose
    T_wc = system._pose(system._records[-1]) @ se3_exp(torch.tensor([0.0, 0.0, 0.01, 0.0, 0.02, 0.0],
                                                                    dtype=torch.float64))
    kviews = system._rerectified(views, system._turn_from_last(T_wc, frames[3].timestamp))
    expected, _ = rectify_image(frames[3].image, source_pixels(frames[3].camera, frames[3].camera,
                                                               0.5 * torch.tensor([0.0, 0.02, 0.0])))
    assert torch.allclose(kviews.frame.image, expected, atol=1e-5)
    plain = CodeSLAM(small_config(size=3), standin_depth_model(num_levels=3))
    plain.camera = frames[0].camera
    assert torch.equal(plain._views(frames[3]).frame.image, frames[3].image)


def test_the_motion_models_velocity_leaves_out_the_windows_correction_of_a_new_keyframe():
    """A frame that became a keyframe is re-expressed relative to itself and the window then moves it: the
    velocity up to it is the motion as the two frames were tracked against their common keyframe, not the jump
    to the keyframe's corrected pose (on the generator's fast turn such a jump was 7 cm against 2 mm of motion)."""
    from types import SimpleNamespace

    from codeslam.geometry.lie import se3_exp, se3_inverse
    from codeslam.slam.system import _FrameRecord

    system = CodeSLAM(small_config(size=3), standin_depth_model(num_levels=3))
    D = torch.float64
    A = se3_exp(torch.tensor([0.01, 0.0, 0.002, 0.0, 0.02, 0.0], dtype=D))  # frame 1 in keyframe 0
    B = se3_exp(torch.tensor([0.02, 0.0, 0.004, 0.0, 0.04, 0.0], dtype=D))  # frame 2 in keyframe 0, as tracked
    correction = se3_exp(torch.tensor([0.07, -0.03, 0.0, 0.01, 0.0, 0.0], dtype=D))  # the window's
    T0 = se3_exp(torch.tensor([0.3, 0.1, -0.2, 0.1, -0.2, 0.3], dtype=D))
    system.keyframes = [SimpleNamespace(T_wc=T0), SimpleNamespace(T_wc=T0 @ B @ correction)]
    eye = torch.eye(4, dtype=D)
    system._records = [_FrameRecord(1, 0.1, 0, A, True, None, 0, A),
                       _FrameRecord(2, 0.2, 1, eye, True, None, 0, B)]  # frame 2 became keyframe 1
    torch.testing.assert_close(system._last_motion()[0], se3_inverse(A) @ B)
    # the next frame, tracked against keyframe 1: the motion from the keyframe is the keyframe-relative pose
    C = se3_exp(torch.tensor([0.02, 0.0, 0.0, 0.0, 0.02, 0.0], dtype=D))
    system._records.append(_FrameRecord(3, 0.3, 1, C, True, None, 1, C))
    torch.testing.assert_close(system._last_motion()[0], C)


def test_the_motion_model_predicts_with_the_velocity_over_the_time_to_the_frame():
    """Constant velocity over time, not over frames: a frame after dropped ones is predicted Exp(s Log M) from the
    last pose, s its interval over the last motion's in whole frame periods; evenly timed frames, the timestamps'
    jitter included, repeat the motion exactly."""
    from types import SimpleNamespace

    from codeslam.geometry.lie import se3_exp, se3_inverse
    from codeslam.slam.system import _FrameRecord

    system = CodeSLAM(small_config(size=3), standin_depth_model(num_levels=3))
    D = torch.float64
    ref = SimpleNamespace(T_wc=torch.eye(4, dtype=D))
    system.keyframes = [ref]
    xi = torch.tensor([0.08, -0.01, 0.02, 0.01, 0.09, -0.02], dtype=D)  # 8 cm and 5 deg a frame, as on a walk
    A, B = se3_exp(xi), se3_exp(2 * xi)
    system._records = [_FrameRecord(0, 0.0, 0, torch.eye(4, dtype=D), True, None, 0, torch.eye(4, dtype=D)),
                       _FrameRecord(1, 0.1, 0, A, True, None, 0, A), _FrameRecord(2, 0.2, 0, B, True, None, 0, B)]
    M = se3_inverse(A) @ B
    for t in (0.3, 0.3 + 1e-6, 0.33, 0.27):  # one period, to the timestamps' jitter: M itself
        assert torch.equal(system._predict(ref, t), B @ M)
    torch.testing.assert_close(system._predict(ref, 0.7), se3_exp(7 * xi), atol=1e-12, rtol=0)  # four dropped
    torch.testing.assert_close(system._predict(ref, 0.41), se3_exp(4 * xi), atol=1e-12, rtol=0)  # one, late


def test_the_rolling_shutter_rectification_turns_by_one_frame_period_after_dropped_frames():
    """The readout is a fraction of the frame period: after a dropped frame the last motion spans two periods and
    the rectification takes half of its rotation, the keyframe's turn from the last frame likewise (with every
    frame, 0.0117 m on TUM fr1/rpy; rectified by two periods' rotation after each of a tenth dropped, 0.0378 m)."""
    from types import SimpleNamespace

    from codeslam.geometry.lie import se3_exp, so3_log
    from codeslam.slam.system import _FrameRecord

    cfg = small_config(size=3)
    cfg = dataclasses.replace(cfg, tracker=dataclasses.replace(cfg.tracker, rolling_shutter_readout=0.5,
                                                                rolling_shutter_estimate=False))
    system = CodeSLAM(cfg, standin_depth_model(num_levels=3))
    D = torch.float64
    eye = torch.eye(4, dtype=D)
    system.keyframes = [SimpleNamespace(T_wc=eye)]
    system._records = [_FrameRecord(i, 0.1 * i, 0, eye, True, None, 0, eye) for i in range(4)]
    M = se3_exp(torch.tensor([0.0, 0.0, 0.0, 0.02, 0.06, -0.01], dtype=D))
    omega = 0.5 * so3_log(M[:3, :3])
    assert torch.equal(system._readout_rotation(M, 0.1), omega)
    assert torch.equal(system._readout_rotation(M, 0.118), omega)  # jitter: one period
    torch.testing.assert_close(system._readout_rotation(M, 0.2), omega / 2, atol=1e-15, rtol=0)
    torch.testing.assert_close(system._turn_from_last(M, 0.3 + 0.3), so3_log(M[:3, :3]) / 3, atol=1e-15, rtol=0)
    assert torch.equal(system._turn_from_last(M, 0.3 + 0.1), so3_log(M[:3, :3]))


def test_the_motion_priors_interval_runs_from_the_last_tracked_frame():
    """After lost frames the prediction is older than one frame interval: the prior's dt is the time since the
    last frame that was tracked, so the prior is that much looser."""
    from types import SimpleNamespace

    from codeslam.slam.system import _FrameRecord

    system = CodeSLAM(small_config(size=3), standin_depth_model(num_levels=3))
    eye = torch.eye(4, dtype=torch.float64)
    system._records = [_FrameRecord(0, 1.0, 0, eye, True, None, 0, eye)]
    assert system._since_tracked(SimpleNamespace(timestamp=1.1)) == pytest.approx(0.1)
    system._records += [_FrameRecord(i, 1.0 + 0.1 * i, 0, eye, False, None, 0, eye) for i in (1, 2, 3)]
    assert system._since_tracked(SimpleNamespace(timestamp=1.4)) == pytest.approx(0.4)


def test_codes_in_the_decoders_leading_directions(tmp_path):
    # window.code_directions: the tracker and window see a code of that size; the map's files the network's
    import numpy as np

    from codeslam.slam.pipeline import write_keyframes

    frames = synth_frames(3, 16, 7.5)
    seq = MemorySequence(frames)
    system = CodeSLAM(small_config(size=3, code_directions=8), standin_depth_model(num_levels=3))
    run = run_slam(seq, system, frames[0].camera)
    ev = evaluate_run(run.trajectory, ground_truth(seq, range(len(seq))))
    assert all(r.tracking_ok for r in run.results)
    assert ev["ate_sim3_rmse"] < 0.25 * ev["no_motion_ate_rmse_aligned"]
    moved = [k for k in run.keyframes if float(k.code.abs().max()) > 0]
    assert moved  # the window did move codes in the subspace
    for k in run.keyframes:
        assert k.code.shape == (8,) and k.code_basis.shape == (32, 8)
        torch.testing.assert_close(k.network_code, k.code_basis @ k.code)
    write_keyframes(tmp_path / "kf.npz", run.keyframes, frames[0].camera)
    codes = np.load(tmp_path / "kf.npz")["code"]
    assert codes.shape == (len(run.keyframes), 32)
    np.testing.assert_allclose(codes[-1], run.keyframes[-1].network_code.double().numpy())


def test_each_keyframe_keeps_the_pose_the_tracker_gave_it(tmp_path):
    # CodeSLAM.keyframe_tracking: the keyframe's frame's tracked pose in its reference, before any window solve.
    # With the window's solves switched off the map keeps the tracked poses, so each keyframe's final pose is its
    # reference's times that record; with solves the window moves them, and the record stays the tracker's.
    import numpy as np

    from codeslam.slam.pipeline import write_keyframes

    frames = synth_frames(3, 16, 7.5)
    config = small_config(size=3)
    still = dataclasses.replace(config, window=dataclasses.replace(
        config.window, sfm=dataclasses.replace(config.window.sfm, max_iterations=(0, 0, 0))))
    runs = {}
    for name, cfg in (("still", still), ("solved", config)):
        seq = MemorySequence(frames)
        runs[name] = run_slam(seq, CodeSLAM(cfg, standin_depth_model(num_levels=3)), frames[0].camera)
    for name, run in runs.items():
        kfs, tracking = run.keyframes, run.keyframe_tracking
        assert len(kfs) >= 3 and len(tracking) == len(kfs) and tracking[0] == (-1, None)
        by_id = {k.id: k for k in kfs}
        moved = 0.0
        for k, (ref, T) in zip(kfs[1:], tracking[1:]):
            assert ref in by_id and ref < k.id
            moved = max(moved, float((by_id[ref].T_wc @ T - k.T_wc).abs().max()))
        if name == "still":
            assert moved < 1e-6  # project_to_se3 of the composed pose: rounding only
        else:
            assert moved > 1e-4  # the window moved them; the record did not follow
    run = runs["solved"]
    write_keyframes(tmp_path / "kf.npz", run.keyframes, frames[0].camera, run.keyframe_tracking)
    z = np.load(tmp_path / "kf.npz")
    assert z["tracked_from"][0] == -1 and np.isnan(z["T_tracked"][0]).all()
    np.testing.assert_array_equal(z["tracked_from"][1:], [r for r, _ in run.keyframe_tracking[1:]])
    np.testing.assert_allclose(z["T_tracked"][1:], np.stack([T.numpy() for _, T in run.keyframe_tracking[1:]]))


def test_a_free_scale_per_keyframe(tmp_path):
    # window.free_scale: the codes carry one more entry, a log scale the window moves; the map's files hold the
    # network's code and each keyframe's depth is its unscaled depth times exp(s)
    import numpy as np

    from codeslam.sfm.decoder import ScaledDecoder
    from codeslam.slam.pipeline import write_keyframes

    frames = synth_frames(3, 16, 7.5)
    seq = MemorySequence(frames)
    config = small_config(size=3, code_directions=8, free_scale=True, map_prior_weight=0.0,  # measured apart only
                          sfm={"geometric_pose_min_std": 0.0})
    system = CodeSLAM(config, standin_depth_model(num_levels=3))
    run = run_slam(seq, system, frames[0].camera)
    ev = evaluate_run(run.trajectory, ground_truth(seq, range(len(seq))))
    assert all(r.tracking_ok for r in run.results)
    assert ev["ate_sim3_rmse"] < 0.25 * ev["no_motion_ate_rmse_aligned"]
    assert any(abs(float(k.code[-1])) > 1e-3 for k in run.keyframes)  # the window moved the scales
    for k in run.keyframes:
        assert k.code.shape == (9,) and k.network_code.shape == (32,)
        torch.testing.assert_close(k.network_code, k.code_basis @ k.code[:-1])
    active = [k for k in run.keyframes if k.active]
    assert active and all(isinstance(k.view.decoder, ScaledDecoder) for k in active)
    k = active[-1]
    unscaled = k.view.decoder.depth(torch.cat([k.code[:-1], torch.zeros(1, dtype=k.code.dtype)]))
    torch.testing.assert_close(k.depth_map(), unscaled * torch.exp(k.code[-1]), rtol=1e-5, atol=1e-6)
    write_keyframes(tmp_path / "kf.npz", run.keyframes, frames[0].camera)
    assert np.load(tmp_path / "kf.npz")["code"].shape == (len(run.keyframes), 32)
