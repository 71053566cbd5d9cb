"""Self-supervised adaptation: the motion chain inverts, the photometric loss is lowest at the true depth and
motion, warm-up motion estimation lowers it, runs resume exactly, and ``codeslam adapt`` writes its outputs."""

from __future__ import annotations

import pytest
import torch

from codeslam.cli import main
from codeslam.data.tum import TumSequence
from codeslam.errors import ConfigError
from codeslam.geometry.camera import canonical_camera
from codeslam.geometry.lie import se3_exp, se3_inverse
from codeslam.network.adapt import AdaptConfig, adapt, chain_poses, photometric_loss, relative_motions
from codeslam.network.model import CodeNetwork, to_network_image
from codeslam.network.weights import read_weights, save_weights
from codeslam.synth.generate import generate_sequence
from codeslam.synth.render import RenderConfig

SIZE = 32


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> TumSequence:
    """8 frames of a generator walk at 5 frames/s (anti-aliased), at the tiny network's canonical camera."""
    out = tmp_path_factory.mktemp("adapt") / "seq"
    generate_sequence(out, 3, 8, camera=canonical_camera(SIZE, SIZE), config=RenderConfig(supersample=2), fps=5,
                      motion="walk")
    return TumSequence(out)


@pytest.fixture(scope="module")
def walk_96(tmp_path_factory) -> TumSequence:
    """The same walk at 96x72: enough pixels for the photometric loss to see depth and motion errors."""
    out = tmp_path_factory.mktemp("adapt96") / "seq"
    generate_sequence(out, 3, 8, camera=canonical_camera(96, 72), config=RenderConfig(supersample=2), fps=5,
                      motion="walk")
    return TumSequence(out)


def _frames(seq: TumSequence):
    images = torch.stack([seq[i].image for i in range(len(seq))]).float()
    depth = torch.stack([seq[i].depth for i in range(len(seq))]).float()
    poses = torch.stack([seq[i].pose for i in range(len(seq))]).double()
    return images, depth, poses


def test_motion_chain_round_trip():
    g = torch.Generator().manual_seed(0)
    T = se3_exp(0.3 * torch.randn(6, 6, generator=g, dtype=torch.float64))
    delta = relative_motions(T)
    assert torch.equal(delta[0], torch.zeros(6, dtype=torch.float64))
    assert torch.allclose(chain_poses(T[0], delta), T, atol=1e-12)


def test_photometric_loss_is_lowest_at_the_true_depth_and_motion(walk_96):
    images, depth, poses = _frames(walk_96)
    gray = to_network_image(images, 1)
    t, s = torch.tensor([3, 4]), torch.tensor([[2, 4], [3, 5]])
    T_st = (se3_inverse(poses[s]) @ poses[t][:, None]).float()
    valid = torch.ones(2, 2, 72, 96, dtype=torch.bool)
    cam = canonical_camera(96, 72)

    def loss(scale: float = 1.0, T=T_st) -> float:
        return float(photometric_loss(gray[t], depth[t][:, None] * scale, gray[s][:, :, 0], valid, T, cam, 0.05))

    best = loss()
    assert best < min(loss(0.7), loss(1.4), loss(2.0)) and best < 0.6 * loss(0.5)
    nudged = T_st @ se3_exp(torch.tensor([0.05, 0.0, 0.0, 0.0, 0.03, 0.0]))
    assert best < 0.85 * loss(T=nudged)


def test_adapt_estimates_motion_then_adapts_and_resumes_exactly(tmp_path, walk, tiny_config):
    images, _, _ = _frames(walk)
    torch.manual_seed(0)
    cfg = AdaptConfig(steps=6, pose_warmup=4, batch=2, log_every=1, checkpoint_every=100, levels=2)

    def fresh() -> CodeNetwork:
        torch.manual_seed(0)
        return CodeNetwork(tiny_config())

    straight = adapt(fresh(), images, tmp_path / "a", cfg)
    assert straight.finished and (tmp_path / "a" / "weights.safetensors").is_file()
    assert straight.poses.shape == (8, 4, 4)
    rows = (tmp_path / "a" / "log.csv").read_text().splitlines()
    assert len(rows) == 7
    anchor = [float(r.split(",")[5]) for r in rows[1:]]
    assert anchor[:4] == [0.0] * 4 and anchor[-1] > 0  # the network is held in the warm-up, then moves
    part = adapt(fresh(), images, tmp_path / "b", cfg, stop_after=3)
    assert not part.finished and not (tmp_path / "b" / "weights.safetensors").exists()
    resumed = adapt(fresh(), images, tmp_path / "b", cfg, resume=True)
    assert resumed.finished
    wa, wb = read_weights(tmp_path / "a" / "weights.safetensors")[0], read_weights(tmp_path / "b" /
                                                                                  "weights.safetensors")[0]
    assert all(torch.allclose(wa[k], wb[k], atol=1e-6) for k in wa)
    start = fresh().state_dict()
    assert any(not torch.equal(wa[k], start[k]) for k in wa)  # the network did change after the warm-up


def test_cli_adapt_writes_weights_and_poses(tmp_path, walk, tiny_config, capsys):
    torch.manual_seed(0)
    save_weights(tmp_path / "tiny.safetensors", CodeNetwork(tiny_config()))
    args = ["adapt", str(walk.root), "--weights",
            str(tmp_path / "tiny.safetensors"), "--out", str(tmp_path / "ad.safetensors"), "--steps", "4",
            "--warmup", "2", "--threads", "1", "-q"]
    assert main(args) == 0
    assert (tmp_path / "ad.safetensors").is_file()
    assert len((tmp_path / "ad_adapt" / "poses.txt").read_text().splitlines()) == 1 + 8
    assert main(args) == 2  # a run is there: --resume or another --out
    assert "--resume" in capsys.readouterr().err
    assert main([*args[:-1], "-q", "--resume"]) == 0
    assert main(["adapt", args[1], "--out", str(tmp_path / "x.safetensors"), "--frames", "0:2", "-q"]) == 2


def test_automask_ignores_what_no_motion_explains(walk_96):
    images, depth, _ = _frames(walk_96)
    gray = to_network_image(images, 1)
    same = gray[3:4, :, None].expand(1, 2, 1, 72, 96)[:, :, 0]  # both "sources" are the target itself
    valid = torch.ones(1, 2, 72, 96, dtype=torch.bool)
    moved = se3_exp(torch.tensor([[0.1, 0.0, 0.0, 0.0, 0.05, 0.0]])).expand(1, 2, 4, 4)  # a wrong motion
    cam = canonical_camera(96, 72)
    plain = float(photometric_loss(gray[3:4], depth[3:4, None], same, valid, moved, cam, 0.05))
    masked = float(photometric_loss(gray[3:4], depth[3:4, None], same, valid, moved, cam, 0.05, automask=True))
    assert plain > 1e-4 and masked == 0.0  # no pixel is explained better by the wrong motion than by none


@pytest.mark.parametrize("trainable", ["zero_code", "all"])
def test_zero_code_adaptation_moves_the_prior_and_keeps_the_code_jacobian(tmp_path, walk, tiny_config, trainable):
    """``trainable='zero_code'`` (the default) adapts D(I, 0) while J(I), the span SLAM optimises codes in, stays
    exactly the start network's; 'all' moves both."""
    images, _, _ = _frames(walk)
    torch.manual_seed(0)
    start = CodeNetwork(tiny_config())
    model = CodeNetwork(tiny_config())
    model.load_state_dict(start.state_dict())
    cfg = AdaptConfig(steps=6, pose_warmup=2, batch=2, levels=2, lr=1e-2, trainable=trainable)
    adapt(model, images, tmp_path / trainable, cfg)
    assert all(p.requires_grad for p in model.parameters())  # the caller's flags are given back

    def decoded(net: CodeNetwork) -> tuple[torch.Tensor, torch.Tensor]:
        net.eval()
        with torch.no_grad():
            x = to_network_image(images[:3], net.config.in_channels)
            feats = net.image_features(x)
            zero = net.decode(feats, feats[0].new_zeros(3, net.code_size))[0]
            J = net.decoder.code_directions(feats, torch.eye(net.code_size))[0]
        return zero, J

    (z0, J0), (z1, J1) = decoded(start), decoded(model)
    assert float((z1 - z0).abs().max()) > 1e-3  # the prior moved
    if trainable == "zero_code":
        assert torch.equal(J1, J0)
    else:
        assert float((J1 - J0).abs().max()) > 1e-4


def test_a_checkpoint_resumes_only_with_the_same_trainable_weights(tmp_path, walk, tiny_config):
    images, _, _ = _frames(walk)
    torch.manual_seed(0)
    cfg = AdaptConfig(steps=4, pose_warmup=2, batch=2, levels=2, trainable="all")
    adapt(CodeNetwork(tiny_config()), images, tmp_path / "r", cfg, stop_after=3)
    with pytest.raises(ConfigError, match="trainable"):
        adapt(CodeNetwork(tiny_config()), images, tmp_path / "r", AdaptConfig(steps=4, pose_warmup=2, batch=2,
                                                                                levels=2), resume=True)
