"""A processed input frame: keypoints with stereo depth, instance labels and map associations."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse


class StereoView:
    """Geometry shared by frames and keyframes: needs `T_c_w`, `keypoints`, `u_right`, `depth`."""

    def __len__(self) -> int:
        return len(self.keypoints)

    @property
    def T_w_c(self) -> np.ndarray:
        return inverse(self.T_c_w)

    @property
    def center_w(self) -> np.ndarray:
        return self.T_w_c[:3, 3]

    def unproject(self, idx: np.ndarray, camera: StereoCamera) -> np.ndarray:
        """World points of keypoints `idx` that have depth (caller selects depth > 0)."""
        X_c = camera.backproject(self.keypoints.uv[idx].astype(float), self.depth[idx])
        T_w_c = self.T_w_c
        return X_c @ T_w_c[:3, :3].T + T_w_c[:3, 3]

    def measurements(self, idx: np.ndarray) -> np.ndarray:
        """(K, 3) stereo measurements [u, v, uR] (uR < 0: monocular) of keypoints `idx`."""
        return np.column_stack([self.keypoints.uv[idx].astype(float), self.u_right[idx].astype(float)])


@dataclass
class Frame(StereoView):
    """Features of one stereo/RGB-D frame (ORB-SLAM2's Frame).

    keypoints: `dynaslam2.features.orb.Keypoints` of the left image (level-0 pixel coordinates).
    u_right / depth: (N,) stereo right-image u and z-depth, -1 where none.
    instance_id / class_id: (N,) MOTS instance id and class id under each keypoint (0 = none).
    static: (N,) features usable for the static map (False on dynamic-class instances in `dynamic` mode).
    point_ids: (N,) associated map point id or -1; outlier: (N,) rejected by the last pose optimization.
    T_c_w: the current estimate (None until tracked).
    """

    index: int
    timestamp: float
    keypoints: object
    u_right: np.ndarray
    depth: np.ndarray
    instance_id: np.ndarray
    class_id: np.ndarray
    static: np.ndarray
    th_depth: float
    T_c_w: np.ndarray | None = None
    point_ids: np.ndarray = field(default=None)
    outlier: np.ndarray = field(default=None)

    def __post_init__(self) -> None:
        n = len(self.keypoints)
        if self.point_ids is None:
            self.point_ids = np.full(n, -1, dtype=np.int64)
        if self.outlier is None:
            self.outlier = np.zeros(n, dtype=bool)

    def tracked_mask(self) -> np.ndarray:
        """Keypoints with a map point that survived the last pose optimization."""
        return (self.point_ids >= 0) & ~self.outlier
