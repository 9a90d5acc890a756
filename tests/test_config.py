"""The typed config tree: YAML layers, `--set` overrides and clear errors."""

import pytest

from dynaslam2.config import SlamConfig, load_config
from dynaslam2.config_tree import to_dict
from dynaslam2.errors import ConfigError


def test_defaults_yaml_and_overrides_layer_in_order(tmp_path):
    path = tmp_path / "cfg.yaml"
    path.write_text("mode: masked\norb:\n  n_features: 1500\n  scale_factor: 1.3\n")
    cfg = load_config(path, ["orb.n_features=800"])
    assert cfg.mode == "masked"
    assert cfg.orb.n_features == 800
    assert cfg.orb.scale_factor == pytest.approx(1.3)
    assert cfg.orb.n_levels == SlamConfig().orb.n_levels


def test_round_trip_through_dict():
    cfg = load_config(None, ["mode=static"])
    assert load_config(None, []).__class__ is SlamConfig
    assert to_dict(cfg)["mode"] == "static"


@pytest.mark.parametrize(
    "override, message",
    [
        ("orb.n_feature=3", "unknown config key orb.n_feature"),
        ("mode=fast", "mode: expected one of"),
        ("orb.n_features=many", "orb.n_features: expected an integer"),
        ("orb.scale_factor=0.9", "orb.scale_factor: expected > 1"),
        ("orb", "expected key=value"),
        ("orb.n_features.x=1", "orb.n_features: expected an integer"),
    ],
)
def test_bad_overrides_name_the_key(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config(None, [override])


def test_bad_yaml_file_is_named(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("orb: [1, 2\n")
    with pytest.raises(ConfigError, match="bad.yaml"):
        load_config(path)
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.yaml")
