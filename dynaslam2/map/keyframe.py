"""Keyframes: frames kept in the map, with their map-point associations."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynaslam2.map.frame import Frame, StereoView


@dataclass
class KeyFrame(StereoView):
    """ORB-SLAM2's KeyFrame: the features of a frame, its pose and its map points.

    point_ids: (N,) map point observed by each keypoint or -1 (kept in sync with `Map`'s
    observation table through `obs_row`). Do not write these arrays directly: use `Map` methods.
    """

    id: int
    frame_index: int
    timestamp: float
    T_c_w: np.ndarray
    keypoints: object
    u_right: np.ndarray
    depth: np.ndarray
    instance_id: np.ndarray
    class_id: np.ndarray
    static: np.ndarray
    th_depth: float
    point_ids: np.ndarray = field(default=None)
    obs_row: np.ndarray = field(default=None)
    bad: bool = False
    segment: int = 0
    object_only: bool = False  # inserted only because an object's tracking was weak (paper III-D)

    def __post_init__(self) -> None:
        n = len(self.keypoints)
        if self.point_ids is None:
            self.point_ids = np.full(n, -1, dtype=np.int64)
        if self.obs_row is None:
            self.obs_row = np.full(n, -1, dtype=np.int64)

    @classmethod
    def from_frame(cls, kf_id: int, frame: Frame, segment: int = 0) -> "KeyFrame":
        return cls(
            id=kf_id, frame_index=frame.index, timestamp=frame.timestamp, T_c_w=frame.T_c_w.copy(),
            keypoints=frame.keypoints, u_right=frame.u_right, depth=frame.depth,
            instance_id=frame.instance_id, class_id=frame.class_id, static=frame.static,
            th_depth=frame.th_depth, segment=segment,
        )

    def matched(self) -> np.ndarray:
        """Indices of keypoints with a map point."""
        return np.flatnonzero(self.point_ids >= 0)
