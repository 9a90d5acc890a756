"""An object's position from its instance mask alone (not in the paper; `objects.mask_measurement`).

An instance with too few close keypoints for a pose (small, far or mostly hidden: on sim `crossing`, 1241 of the
1362 object frames left untracked had fewer than 6 keypoints with depth) still shows its pixels: the depth of the
mask as a whole (stereo: `instance_disparities`; RGB-D: the depth image's median over the mask) and its centroid,
compared with the track's points predicted inside the mask, measure the track's translation, like a box join's
registration does with matched points (the rotation stays the prediction)."""

from __future__ import annotations

import numpy as np

from dynaslam2.classes import instance_class_id
from dynaslam2.config import ObjectsConfig, StereoConfig
from dynaslam2.features.orb import to_gray
from dynaslam2.features.stereo import instance_disparities
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import transform
from dynaslam2.map.frame import Frame


class MaskMeasurement:
    """The instance masks of one frame: their depths (computed on demand, once per instance) and the positions of
    tracks measured from them. `right` for stereo, `depth_image` (metres, 0 = none) for RGB-D."""

    def __init__(self, cfg: ObjectsConfig, stereo: StereoConfig, camera: StereoCamera, instances: np.ndarray,
                 left: np.ndarray, right: np.ndarray | None, depth_image: np.ndarray | None) -> None:
        self.cfg, self.stereo, self.camera = cfg, stereo, camera
        self.instances = instances
        self.left, self.right, self.depth_image = left, right, depth_image
        self._gray: tuple[np.ndarray, np.ndarray] | None = None
        self._depth: dict[int, float | None] = {}

    def instance_ids(self, dynamic_class_ids: np.ndarray) -> np.ndarray:
        """Sorted ids of the instances of `dynamic_class_ids` with >= mask_min_pixels pixels."""
        counts = np.bincount(self.instances.ravel())
        ids = np.flatnonzero(counts >= self.cfg.mask_min_pixels)
        return ids[np.isin(instance_class_id(ids), dynamic_class_ids)]

    def depth(self, inst: int, box: np.ndarray) -> float | None:
        """Depth (m) of instance `inst` (box `box`) as a whole, or None (not found, or beyond max_point_depth_m)."""
        if inst not in self._depth:
            self._depth[inst] = self._measure_depth(inst, box)
        return self._depth[inst]

    def _measure_depth(self, inst: int, box: np.ndarray) -> float | None:
        cfg, cam = self.cfg, self.camera
        if self.depth_image is not None:
            x0, y0, x1, y1 = (int(b) for b in box)
            crop = self.depth_image[y0:y1 + 1, x0:x1 + 1][self.instances[y0:y1 + 1, x0:x1 + 1] == inst]
            crop = crop[crop > 0]
            z = float(np.median(crop)) if len(crop) >= cfg.mask_min_pixels else -1.0
        else:
            if self._gray is None:
                self._gray = (to_gray(self.left), to_gray(self.right))
            d = instance_disparities(*self._gray, self.instances, np.array([inst]), box[None],
                                     cam.bf / cfg.max_point_depth_m, cam.bf / self.stereo.row_search_min_depth_m,
                                     cfg.mask_min_ncc, cfg.mask_uniqueness)[0]
            z = cam.bf / d if d > 0 else -1.0
        return z if 0 < z <= cfg.max_point_depth_m else None

    def position(self, frame: Frame, T_w_o_pred: np.ndarray, X_o: np.ndarray | None, inst: int, box: np.ndarray,
                 min_inside: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(measured position of the object-frame origin (3,), its (3, 3) world information) from instance `inst`
        (box `box`) for an object of points `X_o` (object frame) predicted at `T_w_o_pred`: the predicted position
        moved by the offset between the mask's centroid at the mask's depth and the mean pixel, at the median
        depth, of the points predicted inside the mask (iterated: the points inside the mask once the prediction's
        image offset is applied, 3 times), when >= `min_inside` of them lie inside; `X_o` None (an object with too
        few points to outline it) compares its origin instead. Variances: the centroid mask_centroid_sigma x the box
        size per axis, the disparity mask_disparity_sigma_px. None without a depth or with too few points inside."""
        cam = self.camera
        z_m = self.depth(inst, box)
        if z_m is None:
            return None
        c_m = self._centroid(inst, box)
        shape = X_o is not None
        X_c = transform(frame.T_c_w @ T_w_o_pred, X_o if shape else np.zeros((1, 3)))
        X_c = X_c[X_c[:, 2] > 1e-3]
        if not len(X_c):
            return None
        uv = cam.project(X_c)
        if shape:
            shift = np.zeros(2)
            for _ in range(3):
                p = np.rint(uv + shift).astype(np.int64)
                ok = cam.in_image(p)
                inside = np.zeros(len(p), bool)
                inside[ok] = self.instances[p[ok, 1], p[ok, 0]] == inst
                if np.count_nonzero(inside) < min_inside:
                    return None
                c_p = uv[inside].mean(axis=0)
                shift = c_m - c_p
            z_p = float(np.median(X_c[inside, 2]))
        else:
            c_p, z_p = uv[0], float(X_c[0, 2])
        offset_c = np.subtract(*cam.backproject(np.array([c_m, c_p]), np.array([z_m, z_p])))
        return T_w_o_pred[:3, 3] + frame.T_c_w[:3, :3].T @ offset_c, self._information(frame, c_m, z_m, box)

    def _centroid(self, inst: int, box: np.ndarray) -> np.ndarray:
        """Mean pixel (u, v) of instance `inst`'s mask (box `box`)."""
        x0, y0, x1, y1 = (int(b) for b in box)
        rows, cols = np.nonzero(self.instances[y0:y1 + 1, x0:x1 + 1] == inst)
        return np.array([cols.mean() + x0, rows.mean() + y0])

    def _information(self, frame: Frame, c_m: np.ndarray, z_m: float, box: np.ndarray) -> np.ndarray:
        """(3, 3) world information of a point at mask centroid `c_m` and mask depth `z_m`: the centroid's sigma
        mask_centroid_sigma x the box size per image axis, the depth's from mask_disparity_sigma_px."""
        cfg, cam = self.cfg, self.camera
        x0, y0, x1, y1 = box
        sigma_uv = np.maximum(cfg.mask_centroid_sigma * np.array([x1 - x0 + 1, y1 - y0 + 1]), 1.0)
        sigma_z = z_m**2 / cam.bf * cfg.mask_disparity_sigma_px
        J = np.array([[z_m / cam.fx, 0.0, (c_m[0] - cam.cx) / cam.fx],
                      [0.0, z_m / cam.fy, (c_m[1] - cam.cy) / cam.fy],
                      [0.0, 0.0, 1.0]])  # d(x, y, z) / d(u, v, z)
        cov_c = J @ np.diag([*sigma_uv**2, sigma_z**2]) @ J.T
        R_w_c = frame.T_c_w[:3, :3].T
        return R_w_c @ np.linalg.inv(cov_c) @ R_w_c.T

