"""The SLAM system: one frame in, one estimate out (ORB-SLAM2's System + Tracking state machine,
with local mapping run inline after each new keyframe, in one process)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from dynaslam2.config import SlamConfig
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse
from dynaslam2.io.types import FrameData, ObjectEstimate
from dynaslam2.map.frame import Frame
from dynaslam2.map.keyframe import KeyFrame
from dynaslam2.map.map import Map
from dynaslam2.map.objects import ObjectMap
from dynaslam2.mapping.objects import object_local_ba
from dynaslam2.mapping.local_mapping import LocalMapper
from dynaslam2.tracking.camera import CameraTracker, rigid
from dynaslam2.tracking.frontend import FrameBuilder, uses_depth_image
from dynaslam2.tracking.objects import ObjectTracker
from dynaslam2.tracking.relocalization import relocalize

STATES = ("init", "ok", "lost", "relocalized", "new_segment")


@dataclass
class FrameEstimate:
    """Result of one frame. state: init (first map), ok, lost (pose = motion-model prediction),
    relocalized, new_segment (a new map anchored at the predicted pose). timing_ms holds the stages
    of the results file; mapping_ms the breakdown of local mapping (process, triangulation, fusion,
    ba, kf_culling) on keyframes."""

    index: int
    T_w_c: np.ndarray
    state: str
    n_static_matches: int
    n_dynamic_matches: int
    keyframe: bool
    timing_ms: dict[str, float]
    segment: int = 0
    mapping_ms: dict[str, float] = field(default_factory=dict)
    objects: list[ObjectEstimate] = field(default_factory=list)  # `dynamic` mode: objects seen in this frame

    def status(self) -> dict:
        """The status record of the results files (DESIGN.md status.jsonl)."""
        return {"state": self.state, "n_static_matches": self.n_static_matches,
                "n_dynamic_matches": self.n_dynamic_matches, "keyframe": self.keyframe, "segment": self.segment}


class System:
    """Stereo / RGB-D SLAM. `process(frame)` per frame, in order; deterministic.

    Modes: `static` uses every feature, `masked` never extracts features on (dilated) dynamic-class
    instances; `dynamic` keeps the features of dynamic-class instances off the static map and tracks
    objects with them (`ObjectTracker`, paper III-B to III-D; `self.objects`).
    """

    def __init__(self, config: SlamConfig, camera: StereoCamera) -> None:
        self.config = config
        self.camera = camera
        self.frontend = FrameBuilder(config, camera)
        ext = self.frontend.extractor
        self.tracker = CameraTracker(config, camera, ext.scale_factors, ext.inv_level_sigma2)
        self.mapper = LocalMapper(config, camera, ext.scale_factors)
        self.map = Map(segment=0)
        self.objects = ObjectMap()
        self.object_tracker = (ObjectTracker(config, camera, ext.scale_factors, ext.inv_level_sigma2)
                               if config.mode == "dynamic" else None)
        self.initialized = False
        self.last_frame: Frame | None = None
        self.velocity: np.ndarray | None = None  # T_c_l: last camera -> current camera
        self.ref_kf_id: int | None = None
        # Last frame relative to its reference keyframe, so that it follows BA corrections.
        self.last_T_c_r: np.ndarray | None = None
        self.last_ref_id: int | None = None
        self.last_kf_index = -1
        # Newest keyframe inserted for the camera (not only for an object) and its frame index: the
        # camera's keyframe decision ignores object-only keyframes (`_camera_reference`).
        self.camera_kf_id: int | None = None
        self.last_camera_kf_index = -1
        self.last_reloc_index = -(10**9)
        self.n_lost = 0
        self.n_frames = 0
        self.last_inliers = 0

    # ------------------------------------------------------------------ helpers
    def _update_last_frame(self) -> None:
        """Re-anchor the last frame on its reference keyframe, which local BA may have moved
        (ORB-SLAM2's UpdateLastFrame); otherwise BA corrections leak into the velocity."""
        ref = self.map.keyframes.get(self.last_ref_id) if self.last_ref_id is not None else None
        if self.last_frame is not None and self.last_T_c_r is not None and ref is not None:
            self.last_frame.T_c_w = rigid(self.last_T_c_r @ ref.T_c_w)

    def _predicted_T_c_w(self) -> np.ndarray:
        last = self.last_frame
        if last is None or last.T_c_w is None:
            return np.eye(4)
        if self.velocity is None:
            return last.T_c_w.copy()
        return rigid(self.velocity @ last.T_c_w)

    def _initialize(self, frame: Frame, T_c_w: np.ndarray) -> bool:
        """Map from one stereo/RGB-D frame (ORB-SLAM2's StereoInitialization)."""
        n_depth = int(np.count_nonzero((frame.depth > 0) & frame.static))
        if n_depth < self.config.tracking.init_min_points:
            return False
        frame.T_c_w = T_c_w.copy()
        frame.point_ids[:] = -1
        frame.outlier[:] = False
        # Every point with depth becomes a map point at initialization (new_points_min = all).
        kf = self.mapper.create_keyframe(frame, self.map, new_points_min=len(frame))
        self.map.update_point_descriptors_and_normals(kf.point_ids[kf.matched()], self.mapper.scale_factors)
        self.ref_kf_id = self.camera_kf_id = kf.id
        self.last_kf_index = self.last_camera_kf_index = frame.index
        self.initialized = True
        return True

    def _new_segment(self, frame: Frame, T_c_w: np.ndarray) -> bool:
        """Start a fresh map anchored at `T_c_w` (the motion prior) and keep the world frame."""
        old = self.map
        self.map = Map(segment=old.segment + 1)
        self.mapper.reset()
        if self._initialize(frame, T_c_w):
            return True
        self.map = old
        return False

    # ---------------------------------------------------------------------- main
    def process(self, data: FrameData) -> FrameEstimate:
        """Track one frame; insert a keyframe and run local mapping when needed."""
        t_start = time.perf_counter()
        timing = {"features": 0.0, "stereo": 0.0, "tracking": 0.0, "objects": 0.0, "local_ba": 0.0, "boxes": 0.0}
        frame = self.frontend.build(data, timing)
        t_track = time.perf_counter()
        cfg = self.config.tracking
        keyframe = False
        mapping_ms: dict[str, float] = {}
        self._update_last_frame()
        T_pred = self._predicted_T_c_w()

        if not self.initialized:
            ok = self._initialize(frame, T_pred)
            if not ok:  # too few static points with depth to begin a map: lost, at the motion prior
                frame.T_c_w = T_pred
            state = ("init" if self.map.segment == 0 else "new_segment") if ok else "lost"
            keyframe = ok
            n_inliers = len(self.map.keyframes[self.ref_kf_id].matched()) if ok else 0
        else:
            ok, state, n_inliers = self._track(frame, T_pred)
            if ok:
                object_weak = self._track_objects(frame, data, timing)
                ref = self._camera_reference()
                camera_weak = ref is not None and self.tracker.need_new_keyframe(
                    frame, self.map, ref, n_inliers, frame.index - self.last_camera_kf_index,
                    frame.index - self.last_reloc_index)
                object_weak = [] if frame.index - self.last_kf_index < self.config.objects.kf_min_frames \
                    else object_weak
                if camera_weak or object_weak:
                    kf = self.mapper.create_keyframe(frame, self.map, cfg.new_points_min)
                    kf.object_only = not camera_weak
                    t_map = time.perf_counter()
                    timing["tracking"] = (t_map - t_track) * 1e3 - timing["objects"]
                    mapping_ms = self._local_mapping(frame, kf, camera_weak, object_weak)
                    timing["local_ba"] = (time.perf_counter() - t_map) * 1e3
                    self.ref_kf_id = kf.id
                    self.last_kf_index = frame.index
                    if camera_weak:
                        self.camera_kf_id, self.last_camera_kf_index = kf.id, frame.index
                    keyframe = True
            else:
                self.n_lost += 1
                frame.T_c_w = T_pred
                frame.point_ids[:] = -1
                if self.n_lost > cfg.lost_frames_before_new_segment and self._new_segment(frame, T_pred):
                    state, ok, keyframe = "new_segment", True, True
                    n_inliers = len(self.map.keyframes[self.ref_kf_id].matched())
        self.last_inliers = n_inliers if ok else 0
        if ok:
            if self.last_frame is not None and state in ("ok",) and self.n_lost == 0:
                self.velocity = rigid(frame.T_c_w @ self.last_frame.T_w_c)
            self.n_lost = 0
        ref = self.map.keyframes.get(self.ref_kf_id) if self.ref_kf_id is not None else None
        if ok and ref is not None:
            self.last_T_c_r = frame.T_c_w @ ref.T_w_c
            self.last_ref_id = ref.id
        else:
            self.last_T_c_r, self.last_ref_id = None, None
        if not keyframe:
            timing["tracking"] = (time.perf_counter() - t_track) * 1e3 - timing["objects"]
        self.last_frame = frame
        self.n_frames += 1
        objects = (self.object_tracker.estimates(self.objects, frame.index, self.config.objects.min_output_observations)
                   if self.object_tracker is not None and ok else [])
        timing["total"] = (time.perf_counter() - t_start) * 1e3
        return FrameEstimate(
            index=data.index, T_w_c=inverse(frame.T_c_w), state=state, n_static_matches=int(n_inliers),
            n_dynamic_matches=sum(o.n_points for o in objects), keyframe=keyframe, timing_ms=timing,
            segment=self.map.segment, mapping_ms=mapping_ms, objects=objects,
        )

    def _track_objects(self, frame: Frame, data: FrameData, timing: dict[str, float]) -> list[int]:
        """`dynamic` mode: track the objects of a frame whose camera is tracked; returns the ids of
        weakly tracked objects (III-D)."""
        if self.object_tracker is None:
            return []
        t0 = time.perf_counter()
        rgbd = uses_depth_image(data, self.config)
        weak = self.object_tracker.track(frame, data.instances, self.objects, data.left,
                                         None if rgbd else data.right, data.depth if rgbd else None).weak
        timing["objects"] = (time.perf_counter() - t0) * 1e3
        return weak

    def _camera_reference(self) -> KeyFrame | None:
        """Reference keyframe of the camera's keyframe decision (ORB-SLAM2's NeedNewKeyFrame, paper III-D
        reason (a)): the tracking reference keyframe, or when that was inserted only for an object, the newest
        keyframe inserted for the camera (if still in the map). An object-only keyframe adds no static points
        from its neighbours and, with the BA with objects, no static BA (III-D); as the reference it reset the
        decision (its tracked points are the frame's), so that the camera asked for keyframes, and the static
        map for refinement, less often than in `masked` mode."""
        ref = self.map.keyframes.get(self.ref_kf_id) if self.ref_kf_id is not None else None
        if ref is not None and ref.object_only:
            return self.map.keyframes.get(self.camera_kf_id, ref)
        return ref

    def _local_mapping(self, frame: Frame, kf, camera_weak: bool, object_weak: list[int]) -> dict[str, float]:
        """Local mapping of a new keyframe with the BA case of III-D: camera weak only -> the static
        local BA; an object weak -> BA with objects (object-weak only: the weak objects, or with
        `objects.ba_all_objects` every object observed at the keyframe, and the cameras of the last
        `optim.objects.tail_seconds`; both: everything jointly, after the static local BA when
        `objects.static_ba_first`)."""
        if self.object_tracker is None:
            return self.mapper.process(kf, self.map)
        self.object_tracker.on_keyframe(frame, kf.id, self.objects, object_weak)
        ba_objects = object_weak
        if object_weak and self.config.objects.ba_all_objects:
            # (on_keyframe has just made every observation of this frame a member of the keyframe)
            ba_objects = sorted(t for t, tr in self.objects.tracks.items()
                                if (o := tr.at_frame(frame.index)) is not None and len(o.pt_ids))
        with_objects = bool(ba_objects) and self.config.objects.ba
        static_ba = not with_objects or (camera_weak and self.config.objects.static_ba_first)
        triangulate = camera_weak or self.config.objects.object_keyframe_triangulates
        mapping_ms = self.mapper.process(kf, self.map, static_ba=static_ba, triangulate=triangulate)
        if with_objects:
            t0 = time.perf_counter()
            object_local_ba(kf, self.map, self.objects, ba_objects, camera_weak, self.mapper, self.config)
            mapping_ms["ba"] = mapping_ms.get("ba", 0.0) + (time.perf_counter() - t0) * 1e3
        return mapping_ms

    def _track(self, frame: Frame, T_pred: np.ndarray) -> tuple[bool, str, int]:
        """Camera tracking of an initialized system: (success, state, inliers)."""
        cfg = self.config.tracking
        tracker = self.tracker
        last = self.last_frame
        if self.n_lost == 0:
            n = 0
            if self.velocity is not None:
                n = tracker.track_with_motion_model(frame, last, self.map, T_pred)
            if n < cfg.min_pose_inliers and self.ref_kf_id in self.map.keyframes:
                n = tracker.track_reference_keyframe(frame, self.map.keyframes[self.ref_kf_id], self.map,
                                                     last.T_c_w)
            ok, state = n >= cfg.min_pose_inliers, "ok"
        else:
            frame.T_c_w = T_pred.copy()
            ok = relocalize(frame, self.map, tracker, self.ref_kf_id)
            state = "relocalized"
            if ok:
                self.last_reloc_index = frame.index
        if not ok:
            return False, "lost", 0
        recently = frame.index - self.last_reloc_index < cfg.max_frames
        n_inliers, ref_id = tracker.track_local_map(frame, self.map, state == "relocalized")
        needed = cfg.min_inliers_relocalized if recently else cfg.min_inliers
        if state == "ok":
            # A collapse of the inliers against the last frame signals a jump matched by chance.
            needed = max(needed, cfg.min_inlier_ratio_to_last * self.last_inliers)
        if n_inliers < needed:
            return False, "lost", n_inliers
        if ref_id is not None:
            self.ref_kf_id = ref_id
        return True, state, n_inliers
