"""SLAM configuration: defaults, YAML overlay of nested sections, validation, the resolved config round trip."""

from __future__ import annotations

import pytest

from codeslam.errors import ConfigError
from codeslam.sfm.config import SfMConfig
from codeslam.slam.config import SLAMConfig, WindowConfig, load_config, overlay_config


def test_defaults_are_the_papers_window_and_coarse_to_fine_tracking():
    cfg = SLAMConfig()
    assert cfg.window.size == 4 and cfg.window.marginalise
    assert cfg.tracker.pyramid_levels[0] > cfg.tracker.pyramid_levels[-1] == 0
    assert cfg.decoder_levels == 4
    # the window's solves hold a level's weights (SfMConfig.weights_per_level); `codeslam sfm`'s do not
    assert cfg.window.sfm.weights_per_level and not SfMConfig().weights_per_level
    assert not overlay_config(cfg, {"window": {"sfm": {"weights_per_level": False}}}).window.sfm.weights_per_level


def test_yaml_overlay_of_nested_sections(tmp_path):
    path = tmp_path / "slam.yaml"
    path.write_text(
        "device: cpu\n"
        "tracker:\n  pyramid_levels: [2, 1, 0]\n  max_iterations: [5, 5, 5]\n  min_inlier_ratio: 0.7\n"
        "keyframes:\n  max_rotation_deg: 5\n"
        "window:\n  size: 3\n  sfm:\n    sigma_photometric: 0.1\n    pyramid_levels: [1, 0]\n"
        "    max_iterations: [4, 4]\n"
    )
    cfg = load_config(path)
    assert cfg.tracker.pyramid_levels == (2, 1, 0) and cfg.tracker.min_inlier_ratio == 0.7
    assert cfg.keyframes.max_rotation_deg == 5.0 and isinstance(cfg.keyframes.max_rotation_deg, float)
    assert cfg.window.size == 3 and cfg.window.sfm.sigma_photometric == 0.1
    assert cfg.window.sfm.huber_photometric == SLAMConfig().window.sfm.huber_photometric  # untouched keys stay
    assert cfg.decoder_levels == 3


def test_resolved_config_round_trips_through_yaml(tmp_path):
    cfg = overlay_config(SLAMConfig(), {"window": {"size": 5, "sfm": {"geometric": False}}, "dtype": "float64"})
    path = tmp_path / "resolved.yaml"
    path.write_text(cfg.to_yaml())
    assert load_config(path) == cfg


@pytest.mark.parametrize(
    "text",
    [
        "tracker:\n  bogus: 1\n",  # unknown key
        "bogus_section: {}\n",  # unknown section
        "window:\n  size: 1\n",  # the initialisation needs two keyframes
        "window:\n  size: four\n",  # wrong type
        "tracker:\n  pyramid_levels: [2, 1]\n",  # iterations of another length
        "tracker:\n  motion_model: teleport\n",
        "window:\n  sfm:\n    sigma_photometric: -1\n",
        "window: [1, 2]\n",
        "dtype: float16\n",
        "jacobian_dtype: int8\n",
        "- just\n- a list\n",
        "tracker: {min_overlap: 2}\n",
        "tracker: {rolling_shutter_readout: 1.5}\n",  # more than the frame interval
        "trajectory: smoothed\n",
        "window: {code_directions: -1}\n",
        "window: {window_scale_sigma: -0.1}\n",
        "window: {max_runaway_share: 1.5}\n",
        "window: {map_prior_weight: 1.5}\n",
        "window: {map_prior_blur: 0}\n",
        "tracker: {feature_start_level: -2}\n",
        "tracker: {max_rotation_from_prediction_deg: -5}\n",
        "features: {retry_agreement: 1.5}\n",
        "tracker: {pyramid_levels: [3, 2], max_iterations: [8, 8], feature_start_level: 1}\n",  # finer than all
        "{unbalanced\n",
    ],
)
def test_bad_configs_are_one_line_config_errors(tmp_path, text):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert "\n" not in str(e.value)


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yaml")


def test_empty_file_gives_the_defaults(tmp_path):
    path = tmp_path / "empty.yaml"
    path.write_text("")
    assert load_config(path) == SLAMConfig()
    assert WindowConfig().size == 4


def test_the_rolling_shutter_model_is_refused_in_the_slam_window(tmp_path):
    path = tmp_path / "slam.yaml"
    path.write_text("window:\n  sfm:\n    rolling_shutter: true\n")
    with pytest.raises(ConfigError, match="rolling_shutter is supported by `codeslam sfm` only"):
        load_config(path)


def test_the_free_scale_is_refused_with_the_geometric_term_in_proximity(tmp_path):
    path = tmp_path / "slam.yaml"
    path.write_text("window:\n  free_scale: true\n  sfm:\n    geometric_space: proximity\n")
    with pytest.raises(ConfigError, match="free_scale needs window.sfm.geometric_space: log_depth"):
        load_config(path)
    path.write_text("window:\n  free_scale: true\n")
    with pytest.raises(ConfigError, match="free_scale needs window.map_prior_weight: 0"):
        load_config(path)
    path.write_text("window:\n  free_scale: true\n  map_prior_weight: 0\n")
    with pytest.raises(ConfigError, match="free_scale needs window.sfm.geometric_pose_min_std: 0"):
        load_config(path)
    path.write_text("window:\n  free_scale: true\n  map_prior_weight: 0\n  sfm:\n    geometric_pose_min_std: 0\n")
    assert load_config(path).window.free_scale
