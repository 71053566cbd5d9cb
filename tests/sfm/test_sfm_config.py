"""SfMConfig validation and dict round trip."""

from __future__ import annotations

import pytest

from codeslam.errors import ConfigError
from codeslam.sfm.config import SfMConfig


def test_round_trip_through_a_dict():
    cfg = SfMConfig(sigma_geometric=0.03, pyramid_levels=(1, 0), max_iterations=(5, 5))
    d = cfg.to_dict()
    d["pyramid_levels"] = list(d["pyramid_levels"])  # as YAML gives it
    d["max_iterations"] = list(d["max_iterations"])
    d["affine_prior_sigma"] = list(d["affine_prior_sigma"])
    assert SfMConfig.from_dict(d) == cfg
    assert cfg.residual_types == ("photometric", "geometric")
    assert SfMConfig(geometric=False).residual_types == ("photometric",)


@pytest.mark.parametrize("bad", [
    dict(photometric=False, geometric=False), dict(sigma_photometric=0.0), dict(gradient_mode="central"),
    dict(pyramid_levels=(2, 1, 0), max_iterations=(5,)), dict(damping_decrease=2.0), dict(pyramid_levels=(-1,),
                                                                                         max_iterations=(1,)),
    dict(affine_prior_sigma=(0.1, 0.0)), dict(border=-1.0), dict(geometric_stride=0), dict(geometric_stride=1.5),
])
def test_nonsense_is_refused(bad):
    with pytest.raises(ConfigError):
        SfMConfig(**bad)


def test_unknown_keys_and_wrong_types_are_config_errors():
    with pytest.raises(ConfigError, match="unknown sfm option"):
        SfMConfig.from_dict({"sigma_photo": 0.1})
    with pytest.raises(ConfigError):
        SfMConfig.from_dict({"sigma_photometric": "big"})
    with pytest.raises(ConfigError):
        SfMConfig.from_dict([1, 2])
