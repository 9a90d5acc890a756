"""Data passed between the sequence files, the simulator and the SLAM system."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class FrameData:
    """One synchronized input frame.

    left/right: uint8 HxW (grey) or HxWx3 (RGB); depth: float32 metres along z (0 = none) or None;
    instances: uint16 KITTI-MOTS ids (`class_id*1000 + instance_id`, 0 background, 10000 ignore) or None.
    """

    index: int
    timestamp: float
    left: np.ndarray
    right: np.ndarray | None = None
    depth: np.ndarray | None = None
    instances: np.ndarray | None = None


@dataclass
class ObjectState:
    """Ground truth (or estimate) of one object at one frame.

    T_w_o: 4x4, object frame = box centre, x forward, y left, z up of the vehicle (GT convention).
    v_w, w_w: linear and angular velocity in the world frame (m/s, rad/s).
    dims: (length, width, height) in metres along the object's x, y, z.
    box2d: (left, top, right, bottom) pixels of the visible mask in the left image, or None.
    """

    track_id: int
    cls: str
    T_w_o: np.ndarray
    v_w: np.ndarray
    w_w: np.ndarray
    dims: tuple[float, float, float]
    visible_fraction: float = 1.0
    truncation: float = 0.0
    occlusion: int = 0
    box2d: tuple[float, float, float, float] | None = None
    extra: dict = field(default_factory=dict)
