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


@dataclass
class ObjectEstimate:
    """One estimated (tracked) object at one frame, as `dynaslam2 run` writes it to objects.jsonl/tracks.txt.

    T_w_o: 4x4 estimated object frame (paper III-B): origin = centroid of the object's 3D points at its
      first observation, rotation = identity (world axes) then, moved rigidly with the object since.
    v_w, w_w: linear velocity of the object-frame origin and angular velocity, both in the world frame
      (m/s, rad/s). A tracker that stores the paper's object-frame velocities (eq. 5:
      T_w_o(i+1) = T_w_o(i) [Exp(w_o dt), v_o dt]) converts them with `velocity_to_world`.
    n_points: object points tracked (matched) in this frame.
    instance_id: MOTS id (`class_id*1000 + instance_id`) of the instance mask the object was associated
      with in this frame; 0 when none.
    box2d: (left, top, right, bottom) px of its observed keypoints or of the associated mask, or None.
    T_o_b, dims: 3D box as a pose in the object frame (box frame as the GT convention: box centre,
      x forward, y left, z up) and its (length, width, height) in metres; None until boxes exist.
    """

    track_id: int
    cls: str
    T_w_o: np.ndarray
    v_w: np.ndarray
    w_w: np.ndarray
    n_points: int
    instance_id: int = 0
    box2d: tuple[float, float, float, float] | None = None
    T_o_b: np.ndarray | None = None
    dims: tuple[float, float, float] | None = None

    def T_w_b(self) -> np.ndarray | None:
        """4x4 pose of the 3D box in the world, `T_w_o @ T_o_b`; None without a box."""
        if self.T_o_b is None or self.dims is None:
            return None
        return np.asarray(self.T_w_o, dtype=float) @ np.asarray(self.T_o_b, dtype=float)


def velocity_to_world(T_w_o: np.ndarray, v_o: np.ndarray, w_o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Object-frame velocities of paper eq. 5 -> world frame: (v_w, w_w) = (R_w_o v_o, R_w_o w_o).

    With T_w_o(t+dt) = T_w_o(t) [Exp(w_o dt), v_o dt], the origin moves by R_w_o v_o dt in the world
    and the rotation increment R_w_o Exp(w_o dt) R_w_o^T has the world rotation vector R_w_o w_o dt.
    """
    R_w_o = np.asarray(T_w_o, dtype=float)[:3, :3]
    return R_w_o @ np.asarray(v_o, dtype=float), R_w_o @ np.asarray(w_o, dtype=float)
