"""From input images to a `Frame`: grey conversion, ORB on both images, stereo or RGB-D depth,
instance labels under each keypoint, and the mode switch (static / masked / dynamic)."""

from __future__ import annotations

import time

import cv2
import numpy as np

from dynaslam2.classes import CLASS_IDS, DYNAMIC_CLASSES, instance_class_id
from dynaslam2.config import SlamConfig
from dynaslam2.errors import InputError
from dynaslam2.features.orb import Keypoints, ORBExtractor, to_gray
from dynaslam2.features.stereo import depth_from_image, match_stereo, search_stereo_rows
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.io.types import FrameData
from dynaslam2.map.frame import Frame

DYNAMIC_CLASS_IDS = np.array(sorted(CLASS_IDS[c] for c in DYNAMIC_CLASSES), dtype=np.int64)


def dynamic_mask(instances: np.ndarray) -> np.ndarray:
    """HxW bool: pixels of dynamic-class instances."""
    cls = instance_class_id(instances)
    dynamic = np.zeros(int(cls.max(initial=0)) + 1, bool)  # class id -> dynamic (a lookup, not np.isin)
    dynamic[DYNAMIC_CLASS_IDS[DYNAMIC_CLASS_IDS < len(dynamic)]] = True
    return dynamic[cls]


def uses_depth_image(data: FrameData, config: SlamConfig) -> bool:
    """Whether depth comes from `data`'s depth image (RGB-D) rather than stereo matching."""
    return data.depth is not None and (data.right is None or config.tracking.use_depth_image)


def dilate_mask(mask: np.ndarray, dilation_px: int) -> np.ndarray:
    """HxW bool `mask` dilated by `dilation_px` (DynaSLAM's mask of the dynamic instances)."""
    if dilation_px <= 0 or not mask.any():
        return mask
    k = 2 * dilation_px + 1
    return cv2.dilate(mask.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool)


class FrameBuilder:
    """Builds `Frame`s for one camera and config (ORB-SLAM2's Frame constructor)."""

    def __init__(self, config: SlamConfig, camera: StereoCamera) -> None:
        self.config = config
        self.camera = camera
        self.extractor = ORBExtractor(config.orb)
        self.th_depth = config.stereo.th_depth_baselines * camera.baseline
        self.n_features_right = max(1, round(config.stereo.right_features_factor * config.orb.n_features))

    def check(self, data: FrameData) -> None:
        """InputError naming what `data` lacks for this camera and mode: image sizes, a right or depth image, the
        instance masks of `masked` and `dynamic`, the depth image of tracking.use_depth_image."""
        shape = (self.camera.height, self.camera.width)
        if data.left.shape[:2] != shape:
            raise InputError(f"frame {data.index}: left image is {data.left.shape[1]}x{data.left.shape[0]}, "
                             f"expected {shape[1]}x{shape[0]} from the calibration")
        for name in ("right", "depth", "instances"):
            img = getattr(data, name)
            if img is not None and img.shape[:2] != data.left.shape[:2]:
                raise InputError(f"frame {data.index}: {name} image is {img.shape[1]}x{img.shape[0]}, "
                                 f"expected {shape[1]}x{shape[0]} like the left image")
        if data.right is None and data.depth is None:
            raise InputError(f"frame {data.index}: needs a right image or a depth image")
        if self.config.mode in ("masked", "dynamic") and data.instances is None:
            raise InputError(f"frame {data.index}: mode '{self.config.mode}' needs instance masks (instances/), "
                             "which this sequence lacks; mode 'static' needs none")
        if self.config.tracking.use_depth_image and data.depth is None:
            raise InputError(f"frame {data.index}: tracking.use_depth_image is set but the frame has no depth image "
                             "(depth/)")

    def _row_search(self, kp, on_objects: np.ndarray, pyr_l, pyr_r, u_right: np.ndarray, depth: np.ndarray,
                    instances: np.ndarray | None) -> None:
        """Depth by row search (stereo.dynamic_row_search) for the object keypoints
        (`on_objects`) that `match_stereo` left without; fills `u_right` and `depth` in place."""
        idx = np.flatnonzero(on_objects & (depth <= 0))
        ur, z = search_stereo_rows(kp, idx, pyr_l, pyr_r, self.camera, self.config.stereo,
                                   self.config.stereo.row_search_min_depth_m, self.config.objects.max_point_depth_m,
                                   instances if self.config.stereo.row_search_instance_mask else None)
        found = z > 0
        u_right[idx[found]] = ur[found]
        depth[idx[found]] = z[found]

    def _mask_descriptors(self, kp: Keypoints, pyr_l: list[np.ndarray], objects_px: np.ndarray,
                          on_objects: np.ndarray) -> None:
        """Orientation and descriptors of the keypoints `on_objects` (after stereo matching, which compares
        the original ones with the right image's) recomputed on the pyramid of the left image with every
        pixel off the dynamic-class instances (`objects_px`) set to mid-grey: a keypoint on an object's
        outline then describes the object's side of it, not the background that slides behind a moving
        object."""
        idx = np.flatnonzero(on_objects)
        if len(idx) == 0:
            return
        blanked = np.where(objects_px, pyr_l[0], np.uint8(128))
        kp.angle[idx], kp.desc[idx] = self.extractor.describe(self.extractor.build_pyramid(blanked), kp, idx)

    def _pixels(self, kp: Keypoints) -> tuple[np.ndarray, np.ndarray]:
        """(column, row) of the level-0 pixel nearest to each keypoint."""
        col = np.clip(np.rint(kp.uv[:, 0]).astype(np.int64), 0, self.camera.width - 1)
        row = np.clip(np.rint(kp.uv[:, 1]).astype(np.int64), 0, self.camera.height - 1)
        return col, row

    def _densify(self, kp: Keypoints, pyr_l: list[np.ndarray], instances: np.ndarray,
                 objects_px: np.ndarray) -> Keypoints:
        """`kp` followed by the keypoints of one more ORB pass (objects.densify_*) restricted to the
        dynamic-class instances that the passes before gave fewer than densify_below keypoints (small or
        weakly textured objects: a grid distribution leaves them a handful), on levels
        0..densify_max_level, away from the keypoints of those passes (their pixel and its 8 neighbours).
        `objects_px`: `dynamic_mask` of `instances`."""
        col, row = self._pixels(kp)
        ids, counts = np.unique(instances[row, col][objects_px[row, col]], return_counts=True)
        allowed = objects_px & ~np.isin(instances, ids[counts >= self.config.objects.densify_below])
        if not allowed.any():
            return kp
        first = np.zeros(allowed.shape, np.uint8)
        first[row, col] = 1
        allowed &= cv2.dilate(first, np.ones((3, 3), np.uint8)) == 0
        extra = self.extractor.extract(pyr_l, mask=allowed, n_features=self.config.objects.densify_features,
                                       max_level=self.config.objects.densify_max_level)
        return Keypoints.concatenate([kp, extra]) if len(extra) else kp

    def build(self, data: FrameData, timing_ms: dict[str, float]) -> Frame:
        """Extract and match features of `data`; adds `features` and `stereo` to `timing_ms`."""
        self.check(data)
        mode = self.config.mode
        t0 = time.perf_counter()
        objects_px = dyn = None
        if data.instances is not None and mode in ("masked", "dynamic"):
            objects_px = dynamic_mask(data.instances)
            dyn = dilate_mask(objects_px, self.config.tracking.mask_dilation_px)
        pyr_l = self.extractor.build_pyramid(to_gray(data.left))
        # masked: features on dynamic instances are never extracted, the budget goes to the rest (DynaSLAM);
        # dynamic with objects.n_features: the same, then a pass with its own budget on the instances.
        separate = mode == "dynamic" and self.config.objects.n_features > 0
        mask = ~dyn if (dyn is not None and (mode == "masked" or separate)) else None
        use_depth = uses_depth_image(data, self.config)
        if use_depth:
            kp = self.extractor.extract(pyr_l, mask=mask)
        else:  # left and right concurrently with orb.threads > 1 (ORB-SLAM2 extracts them in two threads)
            pyr_r = self.extractor.build_pyramid(to_gray(data.right))
            kp, kp_r = self.extractor.extract_pair(pyr_l, pyr_r, mask, self.n_features_right)
        n_static = len(kp)
        if separate and dyn is not None and objects_px.any():
            cfg = self.config.objects
            on_objects = self.extractor.extract(pyr_l, mask=objects_px, n_features=cfg.n_features,
                                                max_level=cfg.features_max_level)
            kp = Keypoints.concatenate([kp, on_objects]) if len(on_objects) else kp
        n_first = len(kp)
        if mode == "dynamic" and data.instances is not None and self.config.objects.densify_features > 0:
            kp = self._densify(kp, pyr_l, data.instances, objects_px)
        t1 = time.perf_counter()
        n = len(kp)
        col, row = self._pixels(kp)
        if mode != "dynamic":
            static = np.ones(n, dtype=bool)
        elif separate:  # the first pass's keypoints are `masked` mode's, also those an upper level rounds onto `dyn`
            static = np.arange(n) < n_static
        else:
            static = ~dyn[row, col] if dyn is not None else np.ones(n, dtype=bool)
        if use_depth:
            u_right, depth = depth_from_image(kp, data.depth, self.camera)
        else:
            # Each extraction pass takes its own SAD outlier test (`split`): the static keypoints get `masked`
            # mode's depths, whatever the instances' pass matched. The added keypoints (objects.densify_*) get
            # depth from the row search only.
            first = kp if n == n_first else kp.subset(slice(0, n_first))
            u_right, depth = match_stereo(first, kp_r, pyr_l, pyr_r, self.camera, self.extractor.scale_factors,
                                          self.config.stereo, split=n_static)
            none = np.full(n - n_first, -1.0)  # float64 arrays: the row search writes its depths in full precision
            u_right, depth = np.r_[u_right.astype(np.float64), none], np.r_[depth.astype(np.float64), none]
            if mode == "dynamic" and self.config.stereo.dynamic_row_search:
                self._row_search(kp, ~static, pyr_l, pyr_r, u_right, depth, data.instances)
        t2 = time.perf_counter()
        if data.instances is not None:
            instance_id = data.instances[row, col].astype(np.int64)
            class_id = instance_class_id(instance_id)
        else:
            instance_id = np.zeros(n, dtype=np.int64)
            class_id = np.zeros(n, dtype=np.int64)
        if mode == "dynamic" and data.instances is not None and self.config.objects.masked_descriptors:
            self._mask_descriptors(kp, pyr_l, objects_px, objects_px[row, col] & ~static)
        timing_ms["features"] = (t1 - t0 + time.perf_counter() - t2) * 1e3
        timing_ms["stereo"] = (t2 - t1) * 1e3
        return Frame(
            index=data.index, timestamp=data.timestamp, keypoints=kp,
            u_right=np.asarray(u_right, dtype=np.float64), depth=np.asarray(depth, dtype=np.float64),
            instance_id=instance_id, class_id=class_id, static=static, th_depth=self.th_depth,
        )
