"""The SLAM configuration tree: every threshold of the system lives here.

Load with `load_config(yaml_path, ["section.key=value", ...])`. Defaults follow ORB-SLAM2 (ref. [1]
of the paper) and DynaSLAM II where the paper states them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from dynaslam2.config_tree import build, load_yaml, parse_overrides
from dynaslam2.errors import ConfigError

Mode = Literal["dynamic", "masked", "static"]


@dataclass
class ORBConfig:
    """ORB extraction on an image pyramid, distributed over a grid (ORB-SLAM2's ORBextractor)."""

    n_features: int = 2000
    n_levels: int = 8
    scale_factor: float = 1.2
    ini_th_fast: int = 20
    min_th_fast: int = 7
    edge_threshold: int = 19
    patch_size: int = 31
    cell_size: int = 30

    def validate(self) -> None:
        if self.n_features <= 0:
            raise ConfigError(f"orb.n_features: expected a positive integer, got {self.n_features}")
        if self.n_levels < 1:
            raise ConfigError(f"orb.n_levels: expected >= 1, got {self.n_levels}")
        if not self.scale_factor > 1.0:
            raise ConfigError(f"orb.scale_factor: expected > 1, got {self.scale_factor}")


@dataclass
class StereoConfig:
    """Stereo matching (ORB-SLAM2's Frame::ComputeStereoMatches)."""

    th_high: int = 100
    sad_window: int = 5
    sad_search: int = 5
    outlier_sad_factor: float = 1.5 * 1.4
    th_depth_baselines: float = 40.0


@dataclass
class MatcherConfig:
    """Descriptor matching thresholds (ORB-SLAM2's ORBmatcher)."""

    th_high: int = 100
    th_low: int = 50
    nn_ratio: float = 0.9


@dataclass
class SlamConfig:
    """Root of the SLAM configuration."""

    mode: Mode = "dynamic"
    orb: ORBConfig = field(default_factory=ORBConfig)
    stereo: StereoConfig = field(default_factory=StereoConfig)
    matcher: MatcherConfig = field(default_factory=MatcherConfig)


def load_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> SlamConfig:
    """Defaults, then the YAML file at `path` (if any), then `--set key=value` overrides."""
    layers = [load_yaml(path)] if path is not None else []
    layers.append(parse_overrides(list(overrides)))
    return build(SlamConfig, *layers)
