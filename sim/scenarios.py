"""Scenario configuration: one typed dataclass, named built-ins, YAML files and `key=value` overrides.

Camera rule: `fovy_deg` is the vertical field of view; when `fx` is given it wins and the vertical
field of view becomes `2*atan((H/2)/fx)`. Pixels are square (fy = fx) and the principal point is the
image centre `((W-1)/2, (H-1)/2)` (MuJoCo 4.0 convention, pinned by a test).

Speed rule: `object_speed` multiplies every moving object's nominal speed (vehicles ~7-14 m/s,
pedestrians ~1.2-1.6 m/s). Vehicles that follow the ego in its own lane (`following`) never drive
slower than the ego (scale max(object_speed, 1)) so they are not run over. `object_speed=0`
freezes every other object (those ego-lane leaders excepted) where it is at t = 0.

`n_vehicles`/`n_pedestrians` are totals over the modelled street (the ego's route plus
`view_ahead`), placed where the ego will see them; a candidate that would overlap another object,
the ego's clearance or leave the streets is redrawn (up to 40 times) and otherwise dropped, so a
crowded configuration may hold fewer actors than asked for.
`parked_fraction` is the fraction of vehicles (and of pedestrians) that never move.
`occlusion` (0..1) is how much of the view near traffic and occluders cover. At 1, parked vehicles
(more vans and trucks) stand in rows 0.8-2.5 m apart in the stretch the camera sees, standing
pedestrians wait behind parked cars and walkers keep to the kerb, platoons at about the ego's speed
drive close together in the lanes beside the ego and kerbside furniture (hedges, kiosks, trees,
poles) is dense, so objects are partly hidden. At 0, parked vehicles keep 12 m apart, pedestrians
avoid the stretch behind parked vehicles, followers keep 13.5-34 m gaps, traffic prefers the lanes
not beside the ego and furniture is sparse (mean visible fraction ~0.9 in `traffic`, ~0.65 at 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Literal

from dynaslam2.config_tree import build, load_yaml, parse_overrides
from dynaslam2.errors import ConfigError, InputError


@dataclass
class ScenarioConfig:
    """Everything that defines a simulated sequence; the same config and seed give the same sequence."""

    name: str = "traffic"
    layout: Literal["street", "intersection", "following"] = "street"
    seed: int = 0
    frames: int = 100
    fps: float = 10.0
    image_size: tuple[int, int] = (640, 480)  # W, H in pixels ("640x480" on the command line)
    baseline: float = 0.54  # m, right camera at +baseline along the left camera's x axis
    fovy_deg: float = 60.0  # vertical field of view; ignored when fx is set
    fx: float | None = None  # focal length in pixels; overrides fovy_deg
    cam_height: float = 1.65  # m above the road
    znear: float = 0.1  # m, near clipping distance
    zfar: float = 400.0  # m, far clipping distance
    ego_speed: float = 8.0  # m/s nominal
    ego_lane_change: bool = True  # street layout with 2+ lanes: the ego changes lane and back
    n_vehicles: int = 16
    n_pedestrians: int = 6
    parked_fraction: float = 0.35
    object_speed: float = 1.0  # scale on the nominal speed of every moving object
    turn_lateral_accel: float = 3.0  # m/s^2: a vehicle turning at the intersection slows to keep under it
    occlusion: float = 0.3
    texture: Literal["rich", "poor"] = "rich"
    depth: bool = True
    lane_width: float = 3.5  # m
    lanes_per_direction: int = 2
    parking_width: float = 2.5  # m, parking strip at each kerb
    sidewalk_width: float = 4.0  # m
    view_ahead: float = 120.0  # m of street modelled beyond the ego's last position
    curve_deg: float = 15.0  # the street bends by this angle (+ = left, 0 = straight) ...
    curve_start: float = 45.0  # ... starting this far (m) ahead of the ego's start (after the intersection)
    curve_length: float = 120.0  # ... over this length (m), curvature rising and falling smoothly
    texture_px: int = 256  # vehicle textures: pixels per 4 m of the vehicle's length; facades up to twice that

    def validate(self) -> None:
        """Raise ConfigError naming the first field that is out of range."""
        w, h = self.image_size
        checks = [
            ("frames", self.frames >= 1, "an integer >= 1"),
            ("fps", self.fps > 0, "a number > 0"),
            ("image_size", 16 <= w <= 8192 and 16 <= h <= 8192, "WxH with 16 <= W, H <= 8192"),
            ("baseline", self.baseline > 0, "a number > 0 (m)"),
            ("fovy_deg", 1.0 <= self.fovy_deg <= 170.0, "degrees in [1, 170]"),
            ("fx", self.fx is None or self.fx > 0, "a focal length > 0 in pixels, or null"),
            ("cam_height", 0.3 <= self.cam_height <= 5.0, "metres in [0.3, 5]"),
            ("znear", self.znear > 0, "metres > 0"),
            ("zfar", self.zfar > self.znear, "metres > znear"),
            ("ego_speed", 0 <= self.ego_speed <= 40, "m/s in [0, 40]"),
            ("n_vehicles", 0 <= self.n_vehicles <= 200, "an integer in [0, 200]"),
            ("n_pedestrians", 0 <= self.n_pedestrians <= 200, "an integer in [0, 200]"),
            ("parked_fraction", 0 <= self.parked_fraction <= 1, "a fraction in [0, 1]"),
            ("object_speed", 0 <= self.object_speed <= 5, "a scale factor in [0, 5]"),
            ("turn_lateral_accel", 0.5 <= self.turn_lateral_accel <= 15, "m/s^2 in [0.5, 15]"),
            ("occlusion", 0 <= self.occlusion <= 1, "a fraction in [0, 1]"),
            ("lane_width", 2.5 <= self.lane_width <= 6, "metres in [2.5, 6]"),
            ("lanes_per_direction", 1 <= self.lanes_per_direction <= 3, "an integer in [1, 3]"),
            ("parking_width", 2.0 <= self.parking_width <= 5, "metres in [2, 5]"),
            ("sidewalk_width", 2.0 <= self.sidewalk_width <= 10, "metres in [2, 10]"),
            ("view_ahead", 20 <= self.view_ahead <= 1000, "metres in [20, 1000]"),
            ("curve_deg", -60 <= self.curve_deg <= 60, "degrees in [-60, 60]"),
            ("curve_start", -1000 <= self.curve_start <= 10000, "metres in [-1000, 10000]"),
            ("curve_length", 4 * abs(self.curve_deg) <= self.curve_length <= 5000,
             "metres in [4*|curve_deg|, 5000] (a bend no sharper than ~1 deg per 4 m)"),
            ("texture_px", 32 <= self.texture_px <= 1024, "pixels in [32, 1024]"),
        ]
        for field, ok, expected in checks:
            if not ok:
                raise ConfigError(f"scenario {field}: expected {expected}, got {getattr(self, field)!r}")

    @property
    def duration(self) -> float:
        """Seconds covered by the sequence (frames / fps)."""
        return self.frames / self.fps

    @property
    def fovy_effective_deg(self) -> float:
        """Vertical field of view actually used by the cameras (from fx when set)."""
        if self.fx is None:
            return self.fovy_deg
        return math.degrees(2.0 * math.atan(0.5 * self.image_size[1] / self.fx))


_BUILTINS = MappingProxyType({
    "static": MappingProxyType({
        "name": "static", "layout": "street", "n_vehicles": 24, "n_pedestrians": 4,
        "parked_fraction": 1.0, "occlusion": 0.3,
    }),
    "traffic": MappingProxyType({
        "name": "traffic", "layout": "street", "n_vehicles": 16, "n_pedestrians": 6,
        "parked_fraction": 0.35, "occlusion": 0.3,
    }),
    "crossing": MappingProxyType({
        "name": "crossing", "layout": "intersection", "n_vehicles": 18, "n_pedestrians": 10,
        "parked_fraction": 0.3, "occlusion": 0.7, "ego_speed": 7.0,
    }),
    "following": MappingProxyType({
        "name": "following", "layout": "following", "n_vehicles": 10, "n_pedestrians": 3,
        "parked_fraction": 0.2, "occlusion": 0.3, "ego_speed": 9.0,
    }),
})

SCENARIOS: tuple[str, ...] = tuple(_BUILTINS)


def load_scenario(name_or_yaml_path: str, overrides: list[str] | tuple[str, ...] = ()) -> ScenarioConfig:
    """Built-in scenario by name, or a YAML file of ScenarioConfig fields, then `key=value` overrides.

    Unknown scenario -> InputError listing the built-ins; unknown or invalid field -> ConfigError.
    A YAML file may set `base: <built-in>` to start from a built-in.
    """
    if name_or_yaml_path in _BUILTINS:
        layers = [dict(_BUILTINS[name_or_yaml_path])]
    elif name_or_yaml_path.endswith((".yaml", ".yml")) or Path(name_or_yaml_path).is_file():
        data = load_yaml(name_or_yaml_path)
        base = data.pop("base", None)
        if base is not None and base not in _BUILTINS:
            raise ConfigError(f"{name_or_yaml_path}: base {base!r} is not a built-in scenario "
                              f"(known: {', '.join(SCENARIOS)})")
        layers = [dict(_BUILTINS[base])] if base else []
        data.setdefault("name", Path(name_or_yaml_path).stem)
        layers.append(data)
    else:
        raise InputError(f"unknown scenario {name_or_yaml_path!r}: expected one of {', '.join(SCENARIOS)} "
                         "or a YAML file")
    return build(ScenarioConfig, *layers, parse_overrides(list(overrides)))
