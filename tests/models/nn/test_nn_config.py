"""Tests of rfmitsuba.models.nn.config: the network's architecture and number format."""
from __future__ import annotations

import pytest


def test_bad_config_is_an_error():
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.nn import NetConfig

    with pytest.raises(ConfigError, match="width"):
        NetConfig(width=0)
    with pytest.raises(ConfigError, match="gaussian_octaves"):
        NetConfig(gaussian_octaves=-1)


def test_precision_names_are_checked(variant):
    from rfmitsuba.core import backend as B
    from rfmitsuba.core.errors import ConfigError
    from rfmitsuba.models.nn import MLP, NetConfig, resolve_precision

    assert resolve_precision("auto") == ("half" if B.is_cuda() else "single")
    with pytest.raises(ConfigError, match="precision must be one of auto, single, half, got 'double'"):
        MLP(2, 1, width=4, layers=1, seed=0, precision="double")
    with pytest.raises(ConfigError, match="NetConfig.precision"):
        NetConfig(precision="fp16")
