import math

import torch

from codeslam.geometry.proximity import prox_to_depth
from codeslam.sfm.decoder import standin_decoder
from codeslam.slam.map_prior import map_prior


def _decoder(H: int = 48, W: int = 64):
    v, u = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    prox = 0.45 + 0.1 * torch.sin(u / 9.0) * torch.cos(v / 7.0)  # a textured zero code
    return standin_decoder(prox, 8, 3, 1.5, code_offset=torch.zeros(8, dtype=torch.float64))


def _log_depth(dec, level: int = 0) -> torch.Tensor:
    return prox_to_depth(dec.levels[level].prox0.to(torch.float64), dec.avg_depth).log()


def test_weight_zero_leaves_the_decoder_as_it_is():
    dec = _decoder()
    assert map_prior(dec, torch.ones(48, 64, dtype=torch.float64), 0.0, 4.0) is dec


def test_the_map_passes_on_shape_never_scale():
    # The map's depth is the zero code's times 1.7: the same shape at another scale, so the prior must not move.
    dec = _decoder()
    out = map_prior(dec, _log_depth(dec).exp() * 1.7, 0.35, 4.0)
    for a, b in zip(out.levels, dec.levels):
        assert torch.allclose(a.prox0, b.prox0, atol=1e-12)


def test_a_smooth_difference_moves_the_prior_by_its_weight_and_the_jacobian_stays():
    # The map tilted against the network's view by a linear ramp in log depth: away from the borders a
    # normalised Gaussian average reproduces a linear function exactly, so the prior's log depth moves by weight
    # times the ramp (less its median); the code Jacobian and the uncertainty are the network's, untouched.
    dec = _decoder()
    u = torch.arange(64, dtype=torch.float64).expand(48, 64)
    ramp = 0.004 * (u - 20.0)
    out = map_prior(dec, (_log_depth(dec) + ramp).exp(), 0.35, 2.0)
    moved = _log_depth(out) - _log_depth(dec)
    expected = 0.35 * (ramp - ramp.median())
    inner = (slice(7, -7), slice(7, -7))
    assert torch.allclose(moved[inner], expected[inner], atol=1e-9), (moved[inner] - expected[inner]).abs().max()
    assert all(a.jac is b.jac and a.uncertainty is b.uncertainty for a, b in zip(out.levels, dec.levels))
    coarse = _log_depth(out, 1) - _log_depth(dec, 1)  # the coarser levels follow through the image pyramid
    assert float(coarse[3:-3, 3:-3].std()) > 0.5 * float(expected[inner].std())


def test_texture_of_the_map_is_not_passed_on_and_unknown_pixels_stay_the_networks():
    # A checkerboard difference (the finest texture there is) averages away under the low-pass; where the map
    # knows nothing within the low-pass's reach the network's prior stays exactly.
    dec = _decoder()
    v, u = torch.meshgrid(torch.arange(48), torch.arange(64), indexing="ij")
    checker = 0.2 * (((u + v) % 2) * 2 - 1).to(torch.float64)
    depth = (_log_depth(dec) + checker).exp()
    depth[:, 32:] = math.inf
    out = map_prior(dec, depth, 0.35, 2.0)
    moved = _log_depth(out) - _log_depth(dec)
    inner = moved[6:-6, 6:26]
    assert float(inner.std()) < 1e-3 * 0.35 * 0.2, float(inner.std())  # flat: no checkerboard left
    assert torch.equal(out.levels[0].prox0[:, 44:], dec.levels[0].prox0[:, 44:])


def test_too_little_of_the_view_known_keeps_the_networks_prior():
    dec = _decoder()
    depth = _log_depth(dec).exp() * 2.0
    depth[:, 16:] = math.inf  # a quarter of the view
    assert map_prior(dec, depth, 0.35, 2.0) is dec


def test_slam_gives_the_second_keyframe_the_maps_shape_and_keeps_the_first_and_the_scale():
    # Two runs of the same frames, without and with the map's prior: up to the second keyframe they are the same
    # run, so its pose and its network prior agree; with the map's prior its zero code moves by a smooth,
    # median-free change (shape, no scale), and the first keyframe (nothing to splat) keeps the network's.
    from slam_scene import MemorySequence, preset_frames, small_config

    from codeslam.slam.depth import standin_depth_model
    from codeslam.slam.pipeline import run_slam
    from codeslam.slam.system import CodeSLAM

    frames = preset_frames(5, 12, "walk", 10.0, width=64, height=48)
    keyframes = {}
    for weight in (0.0, 0.35):
        system = CodeSLAM(small_config(map_prior_weight=weight), standin_depth_model())
        run_slam(MemorySequence(frames), system, frames[0].camera)
        keyframes[weight] = system.keyframes
    off, on = keyframes[0.0], keyframes[0.35]
    assert len(off) >= 2 and len(on) >= 2
    assert off[1].frame_index == on[1].frame_index and torch.equal(off[1].depth_zero, on[1].depth_zero)

    def prior_log_depth(kf):  # the zero code's depth of the keyframe's decoder, finest level
        return kf.view.decoder.depth(torch.zeros_like(kf.code), 0).log()

    assert on[0].active and on[1].active  # 12 frames: nothing marginalised yet
    assert torch.equal(prior_log_depth(on[0]), prior_log_depth(off[0]))
    change = prior_log_depth(on[1]) - off[1].depth_zero.to(torch.float64).log()
    assert float(change.abs().max()) > 1e-3  # the map moved it
    assert abs(float(change.median())) < 0.02  # no scale passed on
    fine = change[1:-1, 1:-1] - 0.25 * (change[:-2, 1:-1] + change[2:, 1:-1] + change[1:-1, :-2] + change[1:-1, 2:])
    assert float(fine.abs().max()) < 0.05 * float(change.abs().max())  # smooth: the map's texture is not passed on


def test_in_span_the_correction_is_a_code_every_level_shares():
    # Fitted by the code, the prior's change at every level is J_l c for one code c: the zero code becomes
    # D(I, c), so whatever depth the network's span held before it still holds (the stand-in's truth among them).
    dec = _decoder()
    u = torch.arange(64, dtype=torch.float64).expand(48, 64)
    out = map_prior(dec, (_log_depth(dec) + 0.004 * (u - 20.0)).exp(), 0.35, 2.0, in_span=True)
    J0 = dec.levels[0].jac.to(torch.float64).reshape(dec.code_size, -1)
    change0 = (out.levels[0].prox0 - dec.levels[0].prox0).to(torch.float64).reshape(-1)
    c = torch.linalg.lstsq(J0.T, change0[:, None]).solution[:, 0]
    assert float(change0.abs().max()) > 1e-4  # it moved
    assert torch.allclose(J0.T @ c, change0, atol=1e-6 * float(change0.abs().max()))  # inside the span
    for a, b in zip(out.levels[1:], dec.levels[1:]):
        expected = torch.einsum("c,chw->hw", c, b.jac.to(torch.float64))
        assert torch.allclose((a.prox0 - b.prox0).to(torch.float64), expected, atol=1e-9)


def test_slam_with_map_prior_span_moves_the_second_keyframe_inside_its_span():
    # window.map_prior_span reaches the mapper: the second keyframe's zero code moved, and only along its code.
    from slam_scene import MemorySequence, preset_frames, small_config

    from codeslam.slam.depth import standin_depth_model
    from codeslam.slam.pipeline import run_slam
    from codeslam.slam.system import CodeSLAM

    frames = preset_frames(5, 12, "walk", 10.0, width=64, height=48)
    system = CodeSLAM(small_config(map_prior_span=True), standin_depth_model())
    run_slam(MemorySequence(frames), system, frames[0].camera)
    kf = system.keyframes[1]
    network = standin_depth_model()(frames[kf.frame_index])  # the same frame's decoder before the map's prior
    J0 = network.levels[0].jac.to(torch.float64).reshape(network.code_size, -1)
    change = (kf.view.decoder.levels[0].prox0 - network.levels[0].prox0).to(torch.float64).reshape(-1)
    assert float(change.abs().max()) > 1e-4  # the map moved it
    c = torch.linalg.lstsq(J0.T, change[:, None]).solution[:, 0]
    assert torch.allclose(J0.T @ c, change, atol=1e-4 * float(change.abs().max()))
