"""Object tracking of the `dynamic` mode (paper III-B, III-D): association of the dynamic features
with the object points of the map, object pose (constant-velocity prediction, eq. 5, refined by
object pose-only optimization), object creation, track ids, weak-tracking keyframes.

Per frame, after the camera is tracked on static features only:
(a) objects with a known velocity: their points are projected under the eq. (5) prediction and
    matched by projection search;
(b) the others, or those with too few matches in (a): brute-force matching of their points with the
    keypoints of the instance that overlaps their last 2D box most (consecutive frames);
then one pose-only optimization per object from its matches on one instance (of its class, the
unclaimed one holding most of them); an instance holds at most one object, the one whose pose it
supports with the most inliers (an object matched onto a neighbour's instance then tries its own; a
vehicle's claim on an instance outside its predicted 3D extent is refused, `objects.claim_min_extent_fraction`).
Unclaimed instances with enough close keypoints with depth become objects, unless their keypoints
mostly match the points of one map object of their class not seen in this frame (it re-appears: same
track id, so occlusions keep ids, the matching being against the map, not the previous frame) or
their box overlaps the box of an object of their class seen recently (instance-to-instance IoU
association, the frame's instances assigned jointly; failing that, their box centre lies within the
Mahalanobis gate of a velocity-known object's predicted box, `objects.box_gate_chi2`, or, for a vehicle,
their stereo points lie inside its predicted 3D extent, `objects.extent_min_fraction`; all in
`box_association`). Then instances with too few close keypoints keep, by their box alone, a track seen within
`objects.coast_max_s` (a person's: `pedestrian_coast_max_s`; coasting: its id kept, its position measured by the
instance's mask, `mask_measurement`, or else its predicted pose, reported within `objects.report_coast_s`, a
person's within `pedestrian_report_coast_s`). Last, an instance still unclaimed joins a young pedestrian track (no
velocity yet) within the gate of its last box. No claim, vote or box join gives a
person's track an instance whose colour histogram is far from all of its recent ones (`appearance`,
`objects.appearance_max_distance`); an instance left over re-identifies a person's track lost within max_lost_s by
its colours and the gate (`objects.appearance_reid_distance`), and so does an instance with too few keypoints
within pedestrian_coast_max_s when its mask measures the track (`objects.appearance_reid_coasting`). A tentative
track (fewer than `objects.min_output_observations` observations) that finds nothing in a frame is deleted.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dynaslam2.classes import CLASS_IDS, CLASS_NAMES, DYNAMIC_CLASSES, INSTANCE_CLASS_FACTOR, VEHICLE_CLASSES
from dynaslam2.config import SlamConfig
from dynaslam2.eval.objects import box_iou
from dynaslam2.features.matcher import match_descriptors, search_by_projection
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import hat, inverse, make_pose, so3_log, transform
from dynaslam2.io.types import ObjectEstimate, velocity_to_world
from dynaslam2.map.frame import Frame
from dynaslam2.map.objects import ObjectMap, ObjectObservation, ObjectTrack
from dynaslam2.optim.object_pose import object_velocity, optimize_object_pose, predict_object_pose
from dynaslam2.time_windows import within
from dynaslam2.tracking.appearance import gallery_distance, instance_histograms
from dynaslam2.tracking.box_association import (BoxAssociation, implausible_jump, instance_boxes, keypoint_boxes,
                                                  reanchored_pose)
from dynaslam2.tracking.mask_measurement import MaskMeasurement
from dynaslam2.tracking.object_filter import (capped_angular_velocity, filter_position, filter_rotation, gated,
                                               predicted_rotation)

DYNAMIC_CLASS_IDS = np.array(sorted(CLASS_IDS[c] for c in DYNAMIC_CLASSES), dtype=np.int64)


def _instance_class(inst: int) -> str:
    """The class name of instance id `inst` (class id x INSTANCE_CLASS_FACTOR + instance number)."""
    return CLASS_NAMES[inst // INSTANCE_CLASS_FACTOR]


@dataclass
class PoseProposal:
    """An object's pose from its matches keypoint `kp` <-> object point `pts` on instance `instance_id`."""

    T_w_o: np.ndarray
    kp: np.ndarray
    pts: np.ndarray
    inliers: np.ndarray  # (len(kp),) bool
    instance_id: int


@dataclass
class ObjectFrameResult:
    """Objects of one frame: estimates (one per object seen), inlier dynamic matches, and the ids of
    objects whose tracking is weak (III-D: they ask for a keyframe)."""

    estimates: list[ObjectEstimate]
    n_matches: int
    weak: list[int]


def _coasted(obs: ObjectObservation) -> bool:
    """An observation of the instance's box alone: no measurement, no points (its pose is the prediction)."""
    return not obs.measured and obs.n_points == 0


def _seen_within(track: ObjectTrack, obs: ObjectObservation, window_s: float) -> bool:
    """True when the last observation of `track` before `obs` that is not coasted lies within `window_s` of it."""
    for earlier in reversed(track.observations):
        if earlier.frame_index < obs.frame_index and not _coasted(earlier):
            return within(obs.timestamp - earlier.timestamp, window_s)
    return False


def dynamic_keypoints(frame: Frame) -> np.ndarray:
    """(N,) bool: keypoints on dynamic-class instances, kept off the static map."""
    return ~frame.static & (frame.instance_id > 0) & np.isin(frame.class_id, DYNAMIC_CLASS_IDS)


def first_claim(proposals: dict[int, PoseProposal | None], pred: dict[int, np.ndarray]) -> int:
    """The track whose pose proposal claims its instance first: the most inliers; among equal counts, the pose
    nearest its track's prediction `pred` (a neighbour's track whose points also fit the instance had to move
    further to do so), then the lower track id."""
    return min((k for k, p in proposals.items() if p is not None),
               key=lambda k: (-np.count_nonzero(proposals[k].inliers),
                              float(np.linalg.norm(proposals[k].T_w_o[:3, 3] - pred[k][:3, 3])), k))


def rigid_fit(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(..., 4, 4) least-squares rigid T with B ~ T A (Kabsch), batched over (..., N, 3) point sets."""
    ca, cb = A.mean(-2, keepdims=True), B.mean(-2, keepdims=True)
    H = np.swapaxes(A - ca, -1, -2) @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cb[..., 0, :] - np.einsum("...ij,...j->...i", R, ca[..., 0, :])
    return make_pose(R, t)


def ransac_rigid(A: np.ndarray, B: np.ndarray, hypotheses: int, inlier_m: float,
                 rng: np.random.Generator) -> tuple[np.ndarray | None, np.ndarray]:
    """Robust rigid T with B ~ T A from 3D-3D matches: minimal 3-point hypotheses (vectorized), the
    one with most inliers (distance < inlier_m) refitted on its inliers. (None, all False) if < 3."""
    n = len(A)
    if n < 3:
        return None, np.zeros(n, bool)
    idx = np.stack([rng.choice(n, 3, replace=False) for _ in range(hypotheses)])
    T = rigid_fit(A[idx], B[idx])
    pred = np.einsum("hij,nj->hni", T[:, :3, :3], A) + T[:, None, :3, 3]
    inl = np.linalg.norm(pred - B[None], axis=2) < inlier_m
    best = int(np.argmax(inl.sum(1)))
    mask = inl[best]
    if mask.sum() < 3:
        return None, mask
    T_best = rigid_fit(A[mask], B[mask])
    mask = np.linalg.norm(A @ T_best[:3, :3].T + T_best[:3, 3] - B, axis=1) < inlier_m
    return T_best, mask


class ObjectTracker:
    """Algorithms of object tracking; the state lives in `ObjectMap` (and the frame)."""

    def __init__(self, config: SlamConfig, camera: StereoCamera, scale_factors: np.ndarray,
                 inv_level_sigma2: np.ndarray) -> None:
        self.config = config
        self.cfg = config.objects
        self.camera = camera
        self.boxes = BoxAssociation(config.objects, camera)
        self.scale_factors = np.asarray(scale_factors, dtype=np.float64)
        self.inv_level_sigma2 = np.asarray(inv_level_sigma2, dtype=np.float64)

    # ------------------------------------------------------------------ pieces
    def predicted_pose(self, track: ObjectTrack, timestamp: float) -> np.ndarray:
        """T_w_o at `timestamp`: constant velocity (eq. 5) if known, its angular speed clipped to
        max_angular_speed (axis kept), else the last pose."""
        last = track.last
        if not track.velocity_known:
            return last.T_w_o.copy()
        w_o = capped_angular_velocity(last.w_o, self.cfg)
        return predict_object_pose(last.T_w_o, last.v_o, w_o, timestamp - last.timestamp)

    def _world_points(self, frame: Frame, kp: np.ndarray) -> np.ndarray:
        return frame.unproject(kp, self.camera)

    def _close(self, frame: Frame, kp: np.ndarray) -> np.ndarray:
        """Keypoints among `kp` with stereo depth closer than max_point_depth_m."""
        d = frame.depth[kp]
        return kp[(d > 0) & (d <= self.cfg.max_point_depth_m)]

    def _depth_weight(self, frame: Frame, kp: np.ndarray) -> np.ndarray:
        """(K,) depth information 1/sigma_z^2 (1/m^2) of the stereo keypoints `kp`: disparity sigma of
        one pixel at the keypoint's level, sigma_z = z^2 sigma_d / bf; 0 without depth."""
        z = frame.depth[kp]
        zs = np.where(z > 0, z, 1.0)
        return np.where(z > 0, (self.camera.bf / zs**2) ** 2 * self.inv_level_sigma2[frame.keypoints.octave[kp]], 0.0)

    def _disparity_weight(self, frame: Frame, objects: ObjectMap, kp: np.ndarray, pts: np.ndarray) -> np.ndarray | None:
        """(K,) weights of the disparity residuals of the object pose-only optimization (the keypoint's
        sigma over the disparity's): the measured disparity at sigma / pose_disparity_weight, plus the
        depth uncertainty of the object point at the keypoint's depth (its fused depth information,
        which `_depth_weight` counts at a 1 px disparity sigma, scaled to the same sigma). A point first
        placed far away thus weighs little in depth up close instead of being rejected, until fused.
        None when pose_disparity_weight is 0."""
        k = self.cfg.pose_disparity_weight
        if not k:
            return None
        sigma = 1.0 / np.sqrt(self.inv_level_sigma2[frame.keypoints.octave[kp]])
        z = frame.depth[kp]
        with np.errstate(divide="ignore"):
            sigma_z = 1.0 / (k * np.sqrt(objects.points.weight[pts]))
        sigma_d = np.hypot(sigma / k, self.camera.bf / np.where(z > 0, z, 1.0) ** 2 * sigma_z)
        return sigma / sigma_d

    def _fuse_points(self, frame: Frame, objects: ObjectMap, T_w_o: np.ndarray, kp: np.ndarray, pts: np.ndarray) -> None:
        """Average the stereo observations of inlier keypoints `kp` (measured object pose `T_w_o`)
        into their object points `pts`, weighted by depth information, so points first seen far away
        settle where close observations put them (objects.fuse_points; BA refines them on keyframes).
        An observation whose disparity fails fuse_chi2 against its point's at `T_w_o` is left out (a wrong
        stereo match: its depth information, high up close, would move the point and, through
        fuse_shape_only's common shift, every other point)."""
        if not self.cfg.fuse_points:
            return
        close = (frame.depth[kp] > 0) & (frame.depth[kp] <= self.cfg.max_point_depth_m)
        kp, pts = kp[close], pts[close]
        P = objects.points
        consistent = self._disparity_consistent(frame, T_w_o, kp, P.X_o[pts], P.weight[pts])
        kp, pts = kp[consistent], pts[consistent]
        if len(kp) == 0:
            return
        T_o_w = inverse(T_w_o)
        X_o = self._world_points(frame, kp) @ T_o_w[:3, :3].T + T_o_w[:3, 3]
        w_old, w_new = P.weight[pts], self._depth_weight(frame, kp)
        r = X_o - P.X_o[pts]
        if self.cfg.fuse_shape_only and w_new.sum() > 0:
            r -= (w_new[:, None] * r).sum(axis=0) / w_new.sum()
        P.X_o[pts] += (w_new / (w_old + w_new))[:, None] * r
        P.weight[pts] = w_old + w_new

    def _disparity_consistent(self, frame: Frame, T_w_o: np.ndarray, kp: np.ndarray, X_o: np.ndarray,
                              weight: np.ndarray) -> np.ndarray:
        """Mask of the stereo keypoints `kp` whose disparity agrees with that of their object points `X_o` (depth
        information `weight`) placed at `T_w_o`: squared difference within fuse_chi2 of the sum of the two
        variances (1 px at the keypoint's level; the point's depth sigma at its predicted depth)."""
        z_pred = transform(frame.T_c_w @ T_w_o, X_o)[:, 2]
        ahead = z_pred > 0
        zp = np.where(ahead, z_pred, 1.0)
        bf = self.camera.bf
        with np.errstate(divide="ignore"):
            var = 1.0 / self.inv_level_sigma2[frame.keypoints.octave[kp]] + (bf / zp**2) ** 2 / weight
        return ahead & ((bf / frame.depth[kp] - bf / zp) ** 2 <= self.cfg.fuse_chi2 * var)

    def _compact(self, X: np.ndarray) -> np.ndarray:
        """Mask of points within max_point_spread_m of their median (drops mask-border background)."""
        if len(X) == 0:
            return np.zeros(0, bool)
        return np.linalg.norm(X - np.median(X, axis=0), axis=1) <= self.cfg.max_point_spread_m

    def estimate_pose(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_init: np.ndarray,
                      kp: np.ndarray, pts: np.ndarray, robust_init: bool) -> tuple[np.ndarray, np.ndarray] | None:
        """Object pose-only optimization (III-B) of `track` from matches keypoint `kp` <-> point `pts`;
        with `robust_init` the start comes from a 3D-3D RANSAC on the stereo depths. Returns (T_w_o,
        inlier mask) or None when too few inliers, the implied speed (or turn rate, max_turn_rate) is not physical
        or (with the filter) the position fails the validation gate gate_nis."""
        cfg = self.cfg
        X_o = objects.points.X_o[pts]
        if robust_init:
            has_depth = frame.depth[kp] > 0
            if np.count_nonzero(has_depth) >= 3:
                rng = np.random.default_rng(frame.index * 1009 + track.track_id)
                T, _ = ransac_rigid(X_o[has_depth], self._world_points(frame, kp[has_depth]),
                                    cfg.ransac_hypotheses, cfg.ransac_inlier_m, rng)
                if T is not None:
                    T_init = T
        meas = frame.measurements(kp)
        inv_sigma2 = self.inv_level_sigma2[frame.keypoints.octave[kp]]
        T_w_o, inliers = optimize_object_pose(frame.T_c_w, T_init, X_o, meas, inv_sigma2, self.camera,
                                              self.config.optim, self._disparity_weight(frame, objects, kp, pts))
        inliers = np.asarray(inliers, dtype=bool)
        if not np.all(np.isfinite(T_w_o)) or np.count_nonzero(inliers) < cfg.min_inliers:
            return None
        dt = frame.timestamp - track.last.timestamp
        if dt > 0 and np.linalg.norm(T_w_o[:3, 3] - track.last.T_w_o[:3, 3]) > cfg.max_speed_mps * dt:
            return None
        if (dt > 0 and np.isfinite(cfg.max_turn_rate)
                and np.linalg.norm(so3_log(track.last.T_w_o[:3, :3].T @ T_w_o[:3, :3])) > cfg.max_turn_rate * dt):
            return None
        if gated(track, dt, T_w_o[:3, 3],
                 lambda: self._pose_information(frame, objects, T_w_o, kp[inliers], pts[inliers])[0], cfg):
            return None
        return T_w_o, inliers

    # ------------------------------------------------------------------ main
    def track(self, frame: Frame, instances: np.ndarray | None, objects: ObjectMap, image: np.ndarray | None = None,
              right: np.ndarray | None = None, depth_image: np.ndarray | None = None) -> ObjectFrameResult:
        """Track the objects of `frame` (camera pose already estimated), create new ones; see the
        module docstring for the order of the steps. `image` (the left image, with `instances`): the
        instances' appearance (objects.appearance_max_distance); with the `right` image (stereo) or the
        `depth_image` (RGB-D) too, the coasting instances' mask measurements (objects.mask_measurement)."""
        cfg = self.cfg
        t = frame.timestamp
        dyn = dynamic_keypoints(frame)
        free = dyn.copy()  # dynamic keypoints not yet given to an object
        inst_ids = np.unique(frame.instance_id[dyn])
        masks = None
        if cfg.mask_measurement and instances is not None and image is not None and (
                right is not None or depth_image is not None):
            masks = MaskMeasurement(cfg, self.config.stereo, self.camera, instances, image, right, depth_image)
            inst_ids = np.union1d(inst_ids, masks.instance_ids(DYNAMIC_CLASS_IDS))
        boxes = (instance_boxes(instances, inst_ids) if instances is not None
                 else keypoint_boxes(frame, dyn, inst_ids))
        active = [tr for tr in objects.tracks.values()
                  if tr.last.frame_index < frame.index and within(t - tr.last.timestamp, cfg.max_lost_s)]
        pred = {tr.track_id: self.predicted_pose(tr, t) for tr in active}
        hist = (instance_histograms(image, instances, inst_ids, cfg.appearance_bins, cfg.appearance_min_pixels)
                if cfg.appearance_max_distance > 0 and image is not None and instances is not None else None)
        looks = None if hist is None else {tr.track_id: gallery_distance(hist, tr.appearance) for tr in active}
        foreign = self._foreign(looks, inst_ids)
        candidates = self._search_projection(frame, objects, [tr for tr in active if tr.velocity_known], pred, dyn)
        for tr in active:
            if tr.track_id not in candidates:
                match = self._search_overlap(frame, objects, tr, pred[tr.track_id], dyn, inst_ids, boxes)
                if match is not None:
                    candidates[tr.track_id] = match
        # Pose per object on one instance; an instance holds one object: the one whose pose it supports with the
        # most inliers (`first_claim`). An object whose instance went to another tries its next instance.
        claimed: set[int] = set()
        seen: list[int] = []
        proposals = {tid: self._propose(frame, objects, objects.tracks[tid], pred[tid], *candidates[tid], free,
                                        claimed | foreign[tid])
                     for tid in candidates}
        while any(p is not None for p in proposals.values()):
            tid = first_claim(proposals, pred)
            best = proposals.pop(tid)
            inst = int(np.searchsorted(inst_ids, best.instance_id))
            if objects.tracks[tid].cls in cfg.mask_depth_classes and self._successor(
                    frame, objects, [tr for tr in active if tr.track_id not in seen], pred, objects.tracks[tid],
                    boxes[inst]) is not None:
                continue
            kp, pts = best.kp[best.inliers], best.pts[best.inliers]
            claimed.add(best.instance_id)
            self._fuse_points(frame, objects, best.T_w_o, kp, pts)
            self._observe(frame, objects, objects.tracks[tid], best.T_w_o, kp, pts, best.instance_id, boxes[inst])
            free[kp] = False
            seen.append(tid)
            for other, p in proposals.items():
                if p is not None and p.instance_id == best.instance_id:
                    proposals[other] = self._propose(frame, objects, objects.tracks[other], pred[other],
                                                     *candidates[other], free, claimed | foreign[other])
        # Unclaimed instances: re-appearing objects or new ones. The point votes of those with enough close keypoints
        # go first; the instances left are assigned to the unseen tracks jointly by their boxes
        # (`BoxAssociation.assign`), so that a mostly hidden neighbour cannot outbid an object seen whole; an
        # instance with too few keypoints (it coasts, coast_max_s) comes after those with enough in each stage.
        # (Each instance's points once: an instance only takes its own keypoints out of `free`.)
        open_k = [k for k, inst in enumerate(inst_ids.tolist()) if inst not in claimed]
        points = {k: self._instance_points(frame, int(inst_ids[k]), free) for k in open_k}
        enough = {k: len(points[k][0]) >= cfg.min_inliers for k in open_k}
        # The box stages' gallery distances; with appearance_margin_box_joins the margin rule's instances are out.
        box_looks = looks if looks is None or not cfg.appearance_margin_box_joins else {
            tid: np.where(np.isin(inst_ids, list(foreign[tid])), np.inf, d) for tid, d in looks.items()}

        def assign(tracks: list[ObjectTrack], ks: list[int], max_gap_s: float, stages: tuple[str, ...]
                   ) -> dict[int, ObjectTrack | None]:
            """The track each open instance of `ks` joins by `BoxAssociation.assign`; an instance without enough
            keypoints coasts within coast_max_s (a person's: pedestrian_coast_max_s)."""
            classes = [_instance_class(int(inst_ids[k])) for k in ks]
            return dict(zip(ks, self.boxes.assign(
                frame, objects, tracks, pred, boxes[ks], classes,
                [points[k][1] for k in ks], None if box_looks is None else {tid: d[ks] for tid, d in box_looks.items()},
                np.array([max_gap_s if enough[k] else cfg.pedestrian_coast_max_s if cls == "pedestrian"
                          else cfg.coast_max_s for k, cls in zip(ks, classes)]),
                np.array([not enough[k] for k in ks], dtype=bool), stages)))
        voted = {}
        for k in (k for k in open_k if enough[k]):  # a vote needs min_inliers close keypoints (`_join_by_vote`)
            inst = int(inst_ids[k])
            tid, voted[k] = self._join_by_vote(frame, objects, self._unseen(active, seen, inst, foreign), pred,
                                               inst, points[k], boxes[k], free)
            if tid is not None:
                seen.append(tid)
                claimed.add(inst)
        ks = [k for k in open_k if inst_ids[k] not in claimed]
        joined = assign([tr for tr in active if tr.track_id not in seen], ks, cfg.join_max_gap_s,
                        ("moved", "coast-moved", "box", "gate", "extent", "coast-box"))
        by_box = {tr.track_id for tr in joined.values() if tr is not None}
        held = []  # instances that joined no track
        for k, tr in joined.items():
            inst = int(inst_ids[k])
            # A vote whose pose fails (points made far away do not fit one rigid pose) joins like a box join
            # when the instance's box touches the voted track's (`BoxAssociation.touches`), e.g. after the box
            # join's window lapsed.
            vote = voted.get(k)
            if (tr is None and vote is not None and vote.track_id not in seen and vote.track_id not in by_box
                    and self.boxes.touches(frame, objects, vote, pred[vote.track_id], boxes[k])):
                tr = vote
            if tr is not None:
                seen.append(self._box_join(frame, objects, tr, pred[tr.track_id], inst, points[k], boxes[k], free,
                                           masks))
                claimed.add(inst)
            else:
                held.append(k)
        # Last, the young pedestrian tracks without a velocity, by their gate (a group's pedestrian hidden before its
        # track had one, crossing s10), then people's tracks lost within max_lost_s by their appearance (re-anchored
        # on the instance), and the coasting instances by it too when their mask measures the track; then the
        # instances left become new objects.
        gated = [k for k in held if enough[k]]
        unseen = [tr for tr in active if tr.track_id not in seen]
        late = assign(unseen, gated, cfg.join_max_gap_s, ("young",))
        lost = [k for k in gated if late[k] is None]
        reidentified = set()
        slivers = [k for k in held if not enough[k]] if cfg.appearance_reid_coasting else []  # (vehicles: no gallery)
        if looks is not None and cfg.appearance_reid_distance > 0 and (lost or slivers):
            taken = {tr.track_id for tr in late.values() if tr is not None}
            late.update(assign([tr for tr in unseen if tr.track_id not in taken], lost + slivers, cfg.max_lost_s,
                               ("appearance", "coast-appearance")))
            reidentified = {k for k in lost if late[k] is not None}
        for k in held:
            inst, tr = int(inst_ids[k]), late.get(k)
            tid = (self._box_join(frame, objects, tr, pred[tr.track_id], inst, points[k], boxes[k], free, masks,
                                  reanchor=k in reidentified, measured_only=k in slivers)
                   if tr is not None else self._create(
                       frame, objects, inst, points[k], boxes[k], free,
                       masks if self._may_begin_at_mask_depth(frame, objects, active, seen, pred, inst, boxes[k])
                       else None))
            if tid is not None:
                seen.append(tid)
                claimed.add(inst)
        self._cull(objects, seen)
        if hist is not None:
            self._remember_appearance(frame, objects, seen, hist, inst_ids)
        for tr in active:  # tentative and unmatched: deleted (DeepSORT)
            if tr.track_id not in seen and len(tr.observations) < cfg.min_output_observations:
                objects.remove_track(tr.track_id)
        return self._result(frame, objects, seen, dyn)

    def _propose(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray, kp: np.ndarray,
                 pts: np.ndarray, free: np.ndarray, claimed: set[int]) -> PoseProposal | None:
        """The pose of `track` from its matches keypoint `kp` <-> point `pts` kept on one unclaimed instance
        (`_one_instance`), or None; also None for a velocity-known vehicle whose instance's close stereo points (>=
        min_inliers) lie outside its predicted 3D extent (fraction below objects.claim_min_extent_fraction:
        another car, crossing s62)."""
        kp, pts = self._one_instance(frame, track, kp, pts, free, claimed)
        if len(kp) < self.cfg.min_inliers:
            return None
        inst = int(frame.instance_id[kp[0]])
        if self._outside_extent(objects, track, T_w_o_pred, lambda: self._world_points(frame, self._close(
                frame, np.flatnonzero(frame.instance_id == inst))), self.cfg.claim_min_extent_fraction):
            return None
        est = self.estimate_pose(frame, objects, track, T_w_o_pred, kp, pts, robust_init=not track.velocity_known)
        return None if est is None else PoseProposal(est[0], kp, pts, est[1], inst)

    def _outside_extent(self, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray,
                        world_points: Callable[[], np.ndarray], min_fraction: float) -> bool:
        """Whether less than `min_fraction` (0: never) of an instance's close stereo points (`world_points()`, read
        only for a velocity-known vehicle track), when >= min_inliers, lie in the track's predicted 3D extent
        (`BoxAssociation.extent_fraction`)."""
        if not (min_fraction > 0 and track.cls in VEHICLE_CLASSES and track.velocity_known):
            return False
        X_w = world_points()
        return bool(len(X_w) >= self.cfg.min_inliers
                    and self.boxes.extent_fraction(objects, track, T_w_o_pred, [X_w])[0] < min_fraction)

    def _one_instance(self, frame: Frame, track: ObjectTrack, kp: np.ndarray, pts: np.ndarray, free: np.ndarray,
                      claimed: set[int]) -> tuple[np.ndarray, np.ndarray]:
        """The matches keypoint `kp` <-> point `pts` of `track` kept on one instance: the unclaimed
        instance of the track's class that holds most of its free matched keypoints. An object is seen
        on one instance of its class; matches spread over a neighbour (a pedestrian beside a car) took
        tracks to the neighbour's instance, and a new track was created for the object's own."""
        inst = frame.instance_id[kp]
        ok = (free[kp] & (inst // INSTANCE_CLASS_FACTOR == CLASS_IDS[track.cls])
              & ~np.isin(inst, np.fromiter(claimed, np.int64, len(claimed))))
        if not ok.any():
            return kp[:0], pts[:0]
        ids, counts = np.unique(inst[ok], return_counts=True)
        keep = ok & (inst == ids[np.argmax(counts)])
        return kp[keep], pts[keep]

    def _search_projection(self, frame: Frame, objects: ObjectMap, tracks: list[ObjectTrack],
                           pred: dict[int, np.ndarray], dyn: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """(a): project the points of all `tracks` under their predicted poses, one projection search."""
        if not tracks:
            return {}
        ids = np.array([tr.track_id for tr in tracks])
        pts = objects.points.of_tracks(ids)
        if len(pts) == 0:
            return {}
        row = np.searchsorted(np.sort(ids), objects.points.track[pts])
        T_c_o = frame.T_c_w[None] @ np.stack([pred[i] for i in np.sort(ids).tolist()])
        T = T_c_o[row]
        X_c = np.einsum("nij,nj->ni", T[:, :3, :3], objects.points.X_o[pts]) + T[:, :3, 3]
        z = X_c[:, 2]
        zs = np.where(z > 1e-6, z, 1.0)
        cam = self.camera
        uv = np.column_stack([cam.fx * X_c[:, 0] / zs + cam.cx, cam.fy * X_c[:, 1] / zs + cam.cy])
        vis = (z > 1e-6) & cam.in_image(uv)
        pts, uv, zs = pts[vis], uv[vis], zs[vis]
        objects.points.n_visible[pts] += 1
        match = search_by_projection(
            frame.keypoints, uv, objects.points.desc[pts], np.full(len(pts), self.cfg.projection_radius), None,
            uv[:, 0] - cam.bf / zs, frame.u_right, self.config.matcher.th_high, self.cfg.projection_nn_ratio,
            False, available=dyn)
        m = match >= 0
        out = {}
        owner = objects.points.track[pts]
        for tid in ids.tolist():
            sel = m & (owner == tid)
            if np.count_nonzero(sel) >= self.cfg.min_projection_matches:
                out[tid] = (match[sel].astype(np.int64), pts[sel])
        return out

    def _search_overlap(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray,
                        dyn: np.ndarray, inst_ids: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(b): brute-force matching of the object's points with the keypoints of the instance that
        overlaps its (motion-compensated) last box most (the object was seen in the previous frames)."""
        cfg = self.cfg
        box = self.boxes.predicted_box(track, frame, T_w_o_pred, objects)
        if (not within(frame.timestamp - track.last.timestamp, cfg.max_velocity_gap_s) or box is None
                or len(inst_ids) == 0):
            return None
        iou = box_iou(box[None], boxes)[0]
        k = int(np.argmax(iou))
        if iou[k] < cfg.min_overlap_iou:
            return None
        kp = np.flatnonzero(dyn & (frame.instance_id == inst_ids[k]))
        pts = objects.points.of_track(track.track_id)
        m = match_descriptors(objects.points.desc[pts], frame.keypoints.desc[kp], cfg.bf_max_distance, cfg.bf_nn_ratio)
        if len(m) < cfg.min_inliers:
            return None
        return kp[m[:, 1]], pts[m[:, 0]]

    def _observe(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o: np.ndarray, kp: np.ndarray,
                 pts: np.ndarray, instance_id: int, box: np.ndarray, measured: bool = True,
                 position_info: np.ndarray | None = None) -> None:
        """Record the observation of `track` at `frame`, its velocity from the last observation
        (inverse of eq. 5) when the two are close in time, and refresh the matched points.
        `measured=False`: `T_w_o` is a prediction (velocities carried over). `position_info`: (3, 3)
        information of a measured position whose rotation is the prediction (a box join's registration),
        used by the filter instead of the pose-only information. With the filter, a pose-only pose of a class in
        translation_only_classes keeps the predicted rotation (`_predicted_rotation`)."""
        last = track.observations[-1] if track.observations else None
        v_o, w_o = np.zeros(3), np.zeros(3)
        known = False
        if last is not None:
            dt = frame.timestamp - last.timestamp
            if measured and 0 < dt and within(dt, self.cfg.max_velocity_gap_s):
                v_o, w_o = object_velocity(last.T_w_o, T_w_o, dt)
                known = True
            elif not measured:
                v_o, w_o, known = last.v_o.copy(), last.w_o.copy(), track.velocity_known
        if self.cfg.filter:
            if not measured:
                info, rot_cov = None, None
            elif position_info is not None:
                info, rot_cov = position_info, None
            else:
                info, rot_cov = self._pose_information(frame, objects, T_w_o, kp, pts)
            dt = frame.timestamp - last.timestamp if last is not None else 0.0
            T_w_o = T_w_o.copy()
            if rot_cov is not None and last is not None and track.cls in self.cfg.translation_only_classes:
                T_w_o = self._predicted_rotation(objects, track, T_w_o, pts, dt)
                rot_cov, w_o = None, last.w_o.copy()
            if self.cfg.rotation_filter:
                T_w_o[:3, :3], w_o = filter_rotation(track, dt, T_w_o[:3, :3], rot_cov, self.cfg)
            p_w, v_w = filter_position(track, dt, T_w_o[:3, 3], info, self.cfg)
            T_w_o[:3, 3] = p_w
            v_o = T_w_o[:3, :3].T @ v_w
        box2d = None if not np.all(np.isfinite(box)) else tuple(float(b) for b in box)
        track.observations.append(ObjectObservation(
            frame_index=frame.index, timestamp=frame.timestamp, T_w_o=T_w_o, v_o=v_o, w_o=w_o,
            instance_id=instance_id, kp_idx=kp.astype(np.int64), pt_ids=pts.astype(np.int64), box2d=box2d,
            T_c_w=frame.T_c_w.copy(), measured=measured))
        track.velocity_known = known
        P = objects.points
        P.desc[pts] = frame.keypoints.desc[kp]
        P.n_found[pts] += 1

    def _predicted_rotation(self, objects: ObjectMap, track: ObjectTrack, T_w_o: np.ndarray, pts: np.ndarray,
                            dt: float) -> np.ndarray:
        """Pose-only pose `T_w_o` of points `pts` with the track's predicted rotation (the last one turned at its
        capped w_o over `dt`) in place of the measured one, moved so that the points' centroid stays where the
        pose-only put it (objects.translation_only_classes)."""
        R_pred = predicted_rotation(track, dt, self.cfg)
        T = T_w_o.copy()
        T[:3, 3] += (T_w_o[:3, :3] - R_pred) @ objects.points.X_o[pts].mean(axis=0)
        T[:3, :3] = R_pred
        return T

    def _pose_information(self, frame: Frame, objects: ObjectMap, T_w_o: np.ndarray, kp: np.ndarray,
                          pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Precision of a pose-only object pose from the stereo observations of its points (1 px at level 0,
        scaled by the level): the (3, 3) information of the object-frame origin (world; rotation held), sum
        of J^T J / sigma^2 with J = d(u, v, u_right)/d(translation), and the (3, 3) covariance of its rotation
        (object-frame perturbation R Exp(d)), the translation marginalized."""
        T_c_o = frame.T_c_w @ T_w_o
        X_o = objects.points.X_o[pts]
        X_c = X_o @ T_c_o[:3, :3].T + T_c_o[:3, 3]
        X_c[:, 2] = np.maximum(X_c[:, 2], 1e-3)
        J = self.camera.project_stereo_jacobian(X_c)  # d(u, v, u_right) / d X_c
        J[frame.u_right[kp] < 0, 2, :] = 0.0
        R_c_w = frame.T_c_w[:3, :3]
        J6 = np.concatenate([J @ R_c_w, -J @ T_c_o[:3, :3] @ hat(X_o)], axis=2)  # world translation, rotation
        info = np.einsum("n,nki,nkj->ij", self.inv_level_sigma2[frame.keypoints.octave[kp]], J6, J6)
        return info[:3, :3], np.linalg.inv(info + 1e-9 * np.eye(6))[3:, 3:]

    @staticmethod
    def _unseen(active: list[ObjectTrack], seen: list[int], inst: int, foreign: dict[int, set[int]]
                ) -> list[ObjectTrack]:
        """The active tracks of instance `inst`'s class not seen in this frame that do not find it foreign."""
        return [tr for tr in active if tr.track_id not in seen and tr.cls == _instance_class(inst)
                and inst not in foreign[tr.track_id]]

    def _foreign(self, looks: dict[int, np.ndarray] | None, inst_ids: np.ndarray) -> dict[int, set[int]]:
        """Per active track, the instance ids whose colour histogram lies further than appearance_max_distance
        from every one of its gallery (`looks`: per track id, the `gallery_distance` of each instance of `inst_ids`),
        or further by appearance_margin than from another active track's gallery: not the track's object (its pose
        claims and votes skip them)."""
        if looks is None:
            return defaultdict(set)
        d = np.array(list(looks.values())).reshape(len(looks), len(inst_ids))
        far = d > self.cfg.appearance_max_distance
        if self.cfg.appearance_margin > 0 and len(looks) > 1:
            ds = np.where(np.isnan(d), np.inf, d)
            order = np.sort(ds, axis=0)
            others = np.where(ds == order[0], order[1], order[0])  # the nearest other gallery per (track, instance)
            far |= d > others + self.cfg.appearance_margin
        return {tid: set(inst_ids[far[t]].tolist()) for t, tid in enumerate(looks)}

    def _remember_appearance(self, frame: Frame, objects: ObjectMap, seen: list[int], hist: np.ndarray,
                             inst_ids: np.ndarray) -> None:
        """Add the histogram of each seen person's instance in `frame` to its track's gallery (the newest
        appearance_gallery kept; an instance too small to judge adds none). Vehicles keep none: their faces differ
        (crossing s41: a truck's lavender front, then its olive side as it turned, 0.54 from its gallery)."""
        for tid in seen:
            tr = objects.tracks.get(tid)
            if tr is None or tr.cls in VEHICLE_CLASSES or tr.last.frame_index != frame.index:
                continue
            h = hist[np.searchsorted(inst_ids, tr.last.instance_id)]
            if np.all(np.isfinite(h)):
                tr.appearance = [*tr.appearance, h][-self.cfg.appearance_gallery:]

    def _join_by_vote(self, frame: Frame, objects: ObjectMap, unseen: list[ObjectTrack], pred: dict[int, np.ndarray],
                      inst: int, points: tuple[np.ndarray, np.ndarray, int], box: np.ndarray, free: np.ndarray
                      ) -> tuple[int | None, ObjectTrack | None]:
        """An unclaimed instance (`points`: its `_instance_points`) with >= min_inliers close keypoints whose
        keypoints mostly match the points of one unseen track predicted in view (`_vote`, `_in_view`) joins it
        when a pose fits the matches (`_join_by_points`): (the track id or None, the voted track or None)."""
        kp, X_w, _ = points
        if not unseen or len(kp) < self.cfg.min_inliers:
            return None, None
        voted = self._vote(frame, objects, unseen, kp)
        if (voted is None or not self._in_view(frame, objects, voted[0], pred[voted[0].track_id])
                or (self.cfg.vote_spares_successor
                    and self._successor(frame, objects, unseen, pred, voted[0], box) is not None)):
            return None, None
        return self._join_by_points(frame, objects, pred, inst, box, kp, X_w, free, *voted), voted[0]

    def _successor(self, frame: Frame, objects: ObjectMap, unseen: list[ObjectTrack], pred: dict[int, np.ndarray],
                   voted: ObjectTrack, box: np.ndarray) -> ObjectTrack | None:
        """The track begun for the voted (or claiming) track's object while that one was lost, or None: a confirmed
        unseen track (reported: >= min_output_observations observations) of its class, first observed after the voted
        track's last observation, seen in the previous frame on a box that overlaps the instance's `box` by >=
        join_iou (objects.vote_spares_successor; and a pose claim of a class in objects.mask_depth_classes, whose
        successors are begun readily). A tentative one was never reported: the old id back is no switch."""
        cfg = self.cfg
        return next((tr for tr in unseen
                     if tr is not voted and tr.cls == voted.cls and tr.last.frame_index == frame.index - 1
                     and len(tr.observations) >= cfg.min_output_observations
                     and tr.observations[0].frame_index > voted.last.frame_index
                     and self.boxes.overlap(frame, objects, tr, pred[tr.track_id], box) >= cfg.join_iou), None)

    def _box_join(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray, inst: int,
                  points: tuple[np.ndarray, np.ndarray, int], box: np.ndarray, free: np.ndarray,
                  masks: MaskMeasurement | None = None, reanchor: bool = False, measured_only: bool = False
                  ) -> int | None:
        """The instance joins `track` by its box (`BoxAssociation.assign`): the track goes on at its
        constant-velocity prediction, translated by the registration on the keypoints that match its points
        (`_register`; a measurement of its position for the filter, with the registration's information); the
        instance's other close keypoints become its points. Without a registration the observation is the
        prediction; a prediction that has run off (its points would land far from the track's) is re-anchored on
        the instance first (`_reanchor`; always with `reanchor`: a track re-identified by appearance), and a vehicle's
        instance outside its predicted extent adds no points (`_outside_extent`, join_points_min_extent_fraction). An
        instance with fewer than min_inliers close keypoints (coasting) adds no points; its mask measures the track's
        position instead when it can (`masks`, `_mask_register`). A person's (mask_depth_classes) whose keypoints do
        not register, or whose points cannot place it in its coasting mask, measures it by its mask's centre
        (`_mask_centre_register`; a walking person's keypoints seldom match the points it showed before: without,
        its box joins carried a stale prediction on for seconds). With `measured_only` (a coasting instance that
        joined by its colours alone, objects.appearance_reid_coasting) a join its mask does not measure is refused:
        None (in colours alike, a neighbour's sliver 5 m behind took a person's track, crossing s5 f10-f22)."""
        kp, X_w, _ = points
        if len(kp) < self.cfg.min_inliers:
            kp, X_w = kp[:0], X_w[:0]
            T_w_o, kp_in, pt_in, info = self._mask_register(frame, objects, track, T_w_o_pred, masks, inst, box)
            if measured_only and info is None:
                return None
        else:
            T_w_o, kp_in, pt_in, info = self._register(frame, objects, track, T_w_o_pred, kp, X_w)
            if info is None and track.cls in self.cfg.mask_depth_classes:
                T_w_o, _, _, info = self._mask_register(frame, objects, track, T_w_o_pred, masks, inst, box,
                                                        by_centre=True)
        rest = ~np.isin(kp, kp_in)
        if not len(kp_in) and len(kp):
            T_w_o, keep = self._reanchor(frame, objects, track, T_w_o, X_w, always=reanchor)
            if not keep:
                rest[:] = False
            # (a re-anchored track has forgotten its velocity, so the extent rule leaves its points alone)
            if self._outside_extent(objects, track, T_w_o_pred, lambda: X_w, self.cfg.join_points_min_extent_fraction):
                rest[:] = False
        new = objects.add_points(track.track_id, (X_w[rest] - T_w_o[:3, 3]) @ T_w_o[:3, :3],
                                 frame.keypoints.desc[kp[rest]], self._depth_weight(frame, kp[rest]))
        self._observe(frame, objects, track, T_w_o, np.r_[kp_in, kp[rest]], np.r_[pt_in, new], inst, box,
                      measured=info is not None, position_info=info)
        free[kp] = False
        return track.track_id

    def _create(self, frame: Frame, objects: ObjectMap, inst: int, points: tuple[np.ndarray, np.ndarray, int],
                box: np.ndarray, free: np.ndarray, masks: MaskMeasurement | None = None) -> int | None:
        """With >= min_new_points close keypoints (or, on a small instance, >= min_inliers that are >=
        small_new_fraction of its keypoints), the instance creates an object at the centroid of its points with
        identity rotation (III-B); else None. With `masks` (objects.mask_depth_classes), an instance short of close
        keypoints also counts its keypoints without stereo depth, placed at its mask's depth (`_at_mask_depth`)."""
        cfg = self.cfg
        kp, X_w, n_instance = points
        weight = self._depth_weight(frame, kp)
        if len(kp) < cfg.min_new_points and masks is not None:
            kp, X_w, weight = self._at_mask_depth(frame, inst, box, free, masks, kp, X_w, weight)
        enough = len(kp) >= cfg.min_inliers
        if len(kp) < cfg.min_new_points and not (enough and 0 < cfg.small_new_fraction * n_instance <= len(kp)):
            return None
        tr = objects.new_track(_instance_class(inst))
        centroid = X_w.mean(axis=0)
        new = objects.add_points(tr.track_id, X_w - centroid, frame.keypoints.desc[kp], weight)
        self._observe(frame, objects, tr, make_pose(np.eye(3), centroid), kp, new, inst, box)
        free[kp] = False
        return tr.track_id

    def _may_begin_at_mask_depth(self, frame: Frame, objects: ObjectMap, active: list[ObjectTrack], seen: list[int],
                                 pred: dict[int, np.ndarray], inst: int, box: np.ndarray) -> bool:
        """Whether instance `inst` (box `box`) may begin an object at its mask's depth: its class is in
        objects.mask_depth_classes and no unseen track of that class observed within join_max_gap_s could be there
        (its last or predicted box touches `box`; such a track's person, briefly unmatched, would get a new id)."""
        cls = _instance_class(inst)
        return cls in self.cfg.mask_depth_classes and not any(
            tr.cls == cls and tr.track_id not in seen
            and within(frame.timestamp - tr.last.timestamp, self.cfg.join_max_gap_s)
            and self.boxes.touches(frame, objects, tr, pred[tr.track_id], box) for tr in active)

    def _at_mask_depth(self, frame: Frame, inst: int, box: np.ndarray, free: np.ndarray, masks: MaskMeasurement,
                       kp: np.ndarray, X_w: np.ndarray, weight: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The close keypoints `kp` (world points `X_w`, depth information `weight`) of instance `inst` and, when its
        mask's depth z is found within mask_depth_max_m, its free keypoints without stereo depth placed at z (a body
        thin against the stereo noise at its range) with the information of the mask's disparity
        (mask_disparity_sigma_px: a wrong stereo depth seen later then fails the pose-only's disparity test instead
        of being fused in)."""
        z = masks.depth(inst, box)
        if z is None or z > self.cfg.mask_depth_max_m:
            return kp, X_w, weight
        flat = np.flatnonzero(free & (frame.instance_id == inst) & ~(frame.depth > 0))
        X_c = self.camera.backproject(frame.keypoints.uv[flat].astype(float), np.full(len(flat), z))
        w_mask = (self.camera.bf / z**2 / self.cfg.mask_disparity_sigma_px) ** 2
        return (np.r_[kp, flat], np.vstack([X_w, transform(frame.T_w_c, X_c)]),
                np.r_[weight, np.full(len(flat), w_mask)])

    def _instance_points(self, frame: Frame, inst: int, free: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """The free close keypoints of instance `inst` that lie on its compact body, their world points, and
        the instance's number of free keypoints."""
        kp = np.flatnonzero(free & (frame.instance_id == inst))
        n_instance = len(kp)
        kp = self._close(frame, kp)
        X_w = self._world_points(frame, kp)
        ok = self._compact(X_w)
        return kp[ok], X_w[ok], n_instance

    def _vote(self, frame: Frame, objects: ObjectMap, unseen: list[ObjectTrack],
              kp: np.ndarray) -> tuple[ObjectTrack, np.ndarray, np.ndarray] | None:
        """The unseen map object whose points most of the instance's close keypoints `kp` match (>= min_join_matches
        and >= join_ratio of the matches), with those matches (keypoints, points), or None."""
        cfg = self.cfg
        ids = np.array([tr.track_id for tr in unseen])
        pts = objects.points.of_tracks(ids)
        m = match_descriptors(objects.points.desc[pts], frame.keypoints.desc[kp], cfg.bf_max_distance,
                              cfg.bf_nn_ratio)
        if not len(m):
            return None
        owner = objects.points.track[pts[m[:, 0]]]
        votes_id, votes = np.unique(owner, return_counts=True)
        b = int(np.argmax(votes))
        if votes[b] < cfg.min_join_matches or votes[b] < cfg.join_ratio * len(m):
            return None
        sel = owner == votes_id[b]
        return objects.tracks[int(votes_id[b])], kp[m[sel, 1]], pts[m[sel, 0]]

    def _in_view(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray) -> bool:
        """Whether any point of `track` projects into `frame`'s image at its predicted pose: a vote for a track
        predicted out of view is one for a look-alike (following s17: a car that had left by the left border took
        the instance of the next car leaving there 0.8 s later)."""
        T_c_o = frame.T_c_w @ T_w_o_pred
        X_c = transform(T_c_o, objects.points.X_o[objects.points.of_track(track.track_id)])
        X_c = X_c[X_c[:, 2] > 1e-3]
        return bool(len(X_c)) and bool(self.camera.in_image(self.camera.project(X_c)).any())

    def _join_by_points(self, frame: Frame, objects: ObjectMap, pred: dict[int, np.ndarray], inst: int,
                        box: np.ndarray, kp: np.ndarray, X_w: np.ndarray, free: np.ndarray, tr: ObjectTrack,
                        kp_m: np.ndarray, pt_m: np.ndarray) -> int | None:
        """The instance (close keypoints `kp`, world points `X_w`) joins the voted object `tr` (`_vote`: matches
        keypoints `kp_m` <-> points `pt_m`) when a pose fits those matches; the other keypoints become its points."""
        tid = tr.track_id
        est = self.estimate_pose(frame, objects, tr, pred[tid], kp_m, pt_m, True)
        if est is None:
            return None
        T_w_o, inl = est
        kp_in, pt_in = kp_m[inl], pt_m[inl]
        self._fuse_points(frame, objects, T_w_o, kp_in, pt_in)
        rest = ~np.isin(kp, kp_in)
        new = objects.add_points(tid, (X_w[rest] - T_w_o[:3, 3]) @ T_w_o[:3, :3], frame.keypoints.desc[kp[rest]],
                                 self._depth_weight(frame, kp[rest]))
        self._observe(frame, objects, tr, T_w_o, np.r_[kp_in, kp[rest]], np.r_[pt_in, new], inst, box)
        free[kp] = False
        return tid

    def _register(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray,
                  kp: np.ndarray, X_w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """The predicted pose of `track` translated so that its points matched to keypoints `kp` (world
        points `X_w`) land on them, the inlier keypoints and points, and the (3, 3) information of the
        translation: the information-weighted mean of the offsets that lie within register_chi2 of it in
        their stereo uncertainty (`_offset_information`; iterated from the median offset), when >=
        register_min_matches and the validation gate passes (`object_filter.gated`). Else the prediction, no match
        and None: points added at a wrong prediction disagree with the object's others, and the next pose-only
        optimizations jump between the two sets."""
        cfg = self.cfg
        none = np.zeros(0, np.int64)
        pts = objects.points.of_track(track.track_id)
        m = match_descriptors(objects.points.desc[pts], frame.keypoints.desc[kp], cfg.bf_max_distance, cfg.bf_nn_ratio)
        if len(m) < cfg.register_min_matches:
            return T_w_o_pred, none, none, None
        kp_m, pt_m = kp[m[:, 1]], pts[m[:, 0]]
        offset = X_w[m[:, 1]] - (objects.points.X_o[pt_m] @ T_w_o_pred[:3, :3].T + T_w_o_pred[:3, 3])
        W = self._offset_information(frame, objects, kp_m, pt_m, X_w[m[:, 1]])
        shift = np.median(offset, axis=0)
        for _ in range(3):
            r = offset - shift
            inl = np.einsum("ni,nij,nj->n", r, W, r) < cfg.register_chi2
            if np.count_nonzero(inl) < cfg.register_min_matches:
                return T_w_o_pred, none, none, None
            info = W[inl].sum(axis=0)
            shift = np.linalg.solve(info, np.einsum("nij,nj->i", W[inl], offset[inl]))
        T_w_o = T_w_o_pred.copy()
        T_w_o[:3, 3] += shift
        if gated(track, frame.timestamp - track.last.timestamp, T_w_o[:3, 3], lambda: info, cfg):
            return T_w_o_pred, none, none, None
        return T_w_o, kp_m[inl], pt_m[inl], info

    def _mask_register(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray,
                       masks: MaskMeasurement | None, inst: int, box: np.ndarray, by_centre: bool = False
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """`_register` for a coasting instance: the predicted pose of `track` translated to the position its mask
        measures (`MaskMeasurement.position`: against >= register_min_matches of the track's points predicted
        inside it that were matched again after the frame that made them, or against its origin when it has fewer
        than min_inliers points left), no matched points, and the measurement's information, when the
        position filter's validation gate at mask_gate_nis passes (a mask's disparity can take a wrong peak: one
        found 5 m for a person at 22 m); else the prediction, no match and None (also without the filter's state).
        (A box join's points made at a wrong prediction carry wrong depths: 3 of a person's 6 at 14-16 m against
        18.6 m, crossing s40 f40, moved its mask measurement 3 m.) `by_centre`, or a person's (mask_depth_classes)
        mask that its points cannot place (fewer than register_min_matches inside: a walking person's points are
        seldom found again; crossing s92 gt24, unoccluded at 17 m, ran 1-3 m off on a stale prediction for 1.7 s):
        the mask's centre against the body point it was first found at (`_mask_centre_register`), whatever the
        track's points."""
        cfg = self.cfg
        none = np.zeros(0, np.int64)
        if masks is None or not cfg.filter or track.state_mean is None:
            return T_w_o_pred, none, none, None
        measured = None
        if not by_centre:
            pts = objects.points.of_track(track.track_id)
            again = objects.points.n_found[pts] >= 3  # 1 when added, 2 after the observation that made it
            X_o = objects.points.X_o[pts[again]] if len(pts) >= cfg.min_inliers else None
            measured = masks.position(frame, T_w_o_pred, X_o, inst, box, cfg.register_min_matches)
        if measured is None and (by_centre or track.cls in cfg.mask_depth_classes):
            measured = self._mask_centre_register(frame, track, T_w_o_pred, masks, inst, box)
        if measured is None or gated(track, frame.timestamp - track.last.timestamp, measured[0],
                                     lambda: measured[1], cfg, cfg.mask_gate_nis):
            return T_w_o_pred, none, none, None
        T_w_o = T_w_o_pred.copy()
        T_w_o[:3, 3] = measured[0]
        return T_w_o, none, none, measured[1]

    @staticmethod
    def _mask_centre_register(frame: Frame, track: ObjectTrack, T_w_o_pred: np.ndarray, masks: MaskMeasurement,
                              inst: int, box: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The track's origin measured by instance `inst`'s mask as a whole: the mask's centre (its centroid at its
        depth) is the body's point `track.mask_centre_o` (object frame), taken at the first such measurement where
        the prediction puts it, so that the origin stays where it is on the body (a first measurement adds no
        information). (position (3,), information (3, 3)) or None."""
        if track.mask_centre_o is None:
            measured = masks.position(frame, T_w_o_pred, None, inst, box, 1)
            if measured is not None:
                track.mask_centre_o = T_w_o_pred[:3, :3].T @ (measured[0] - T_w_o_pred[:3, 3])
            return None
        R = T_w_o_pred[:3, :3]
        T_centre = T_w_o_pred.copy()
        T_centre[:3, 3] += R @ track.mask_centre_o
        measured = masks.position(frame, T_centre, None, inst, box, 1)
        return None if measured is None else (measured[0] - R @ track.mask_centre_o, measured[1])

    def _offset_information(self, frame: Frame, objects: ObjectMap, kp: np.ndarray, pts: np.ndarray,
                            X_w: np.ndarray) -> np.ndarray:
        """(K, 3, 3) information of the offsets between the stereo points `X_w` of keypoints `kp` and their
        object points `pts` placed by a pose: along the viewing ray the sum of the two depth variances (the
        keypoint's, `_depth_weight`, and the point's fused information), across it 1 px at the keypoint's level
        for each."""
        ray = X_w - frame.T_w_c[:3, 3]
        dist = np.linalg.norm(ray, axis=1)
        ray /= np.maximum(dist, 1e-9)[:, None]
        with np.errstate(divide="ignore"):
            var_along = 1.0 / self._depth_weight(frame, kp) + 1.0 / objects.points.weight[pts]
        var_across = 2.0 * dist**2 / (self.camera.fx**2 * self.inv_level_sigma2[frame.keypoints.octave[kp]])
        along = ray[:, :, None] * ray[:, None, :]
        return along / var_along[:, None, None] + (np.eye(3) - along) / var_across[:, None, None]

    def _reanchor(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray,
                  X_w: np.ndarray, always: bool = False) -> tuple[np.ndarray, bool]:
        """(pose, whether to add the points): the pose at which a box join adds the instance's points `X_w` to
        `track`: the prediction, or, when their median would lie beyond max_point_spread_m of the box of the track's
        points last seen (object frame; a prediction run off, e.g. in depth while the object was seen without stereo)
        or `always` (a track re-identified after up to max_lost_s), the prediction translated so that their median
        lands on those points' median (`reanchored_pose`), with the track's velocity and filter state forgotten.
        Where the filter of a track measured within join_max_gap_s excludes that (`implausible_jump`: a part of a
        long vehicle not seen before, or wrong depths), the prediction, and the points are not added."""
        T_w_o = reanchored_pose(objects, track, T_w_o_pred, X_w, None if always else self.cfg.max_point_spread_m)
        if T_w_o is None:
            return T_w_o_pred, True
        if not always and implausible_jump(track, frame.timestamp, T_w_o[:3, 3], self.cfg):
            return T_w_o_pred, False
        track.state_mean, track.state_cov = None, None
        track.velocity_known = False
        return T_w_o, True

    def _cull(self, objects: ObjectMap, track_ids: list[int]) -> None:
        """Drop object points of the tracked objects that are rarely found where they project."""
        P = objects.points
        pts = P.of_tracks(np.array(track_ids, dtype=np.int64))
        bad = (P.n_visible[pts] >= self.cfg.cull_min_visible) & (
            P.n_found[pts] < self.cfg.cull_found_ratio * P.n_visible[pts])
        P.alive[pts[bad]] = False

    def estimates(self, objects: ObjectMap, frame_index: int, min_observations: int = 1) -> list[ObjectEstimate]:
        """Output of the objects observed at `frame_index` (world-frame velocities), by track id: those whose
        track had at least `min_observations` observations by then (a confirmed track); a coasted observation (its
        instance's box alone, without points or mask measurement: its pose is the prediction, `coast_max_s`) only
        within objects.report_coast_s (a pedestrian's: pedestrian_report_coast_s) of the track's last observation
        with a measurement or points."""
        cfg = self.cfg
        out = []
        for tid in sorted(objects.tracks):
            tr = objects.tracks[tid]
            obs = tr.at_frame(frame_index)
            window_s = cfg.pedestrian_report_coast_s if tr.cls == "pedestrian" else cfg.report_coast_s
            if (obs is None or len(tr.observations) < min_observations
                    or tr.observations[min_observations - 1].frame_index > frame_index
                    or (_coasted(obs) and not _seen_within(tr, obs, window_s))):
                continue
            v_w, w_w = velocity_to_world(obs.T_w_o, obs.v_o, obs.w_o)
            out.append(ObjectEstimate(track_id=tid, cls=tr.cls, T_w_o=obs.T_w_o.copy(), v_w=v_w, w_w=w_w,
                                      n_points=obs.n_points, instance_id=obs.instance_id, box2d=obs.box2d))
        return out

    def _result(self, frame: Frame, objects: ObjectMap, seen: list[int], dyn: np.ndarray) -> ObjectFrameResult:
        weak, n_matches = [], 0
        for tid in sorted(seen):
            tr = objects.tracks[tid]
            obs = tr.last
            n_matches += obs.n_points
            n_features = int(np.count_nonzero(dyn & (frame.instance_id == obs.instance_id)))
            n_tracked = int(np.count_nonzero(~objects.points.coverage[obs.pt_ids]))
            if len(tr.observations) > 1 and n_features >= self.cfg.weak_min_features \
                    and n_tracked < min(self.cfg.weak_max_tracked, self.cfg.weak_tracked_ratio * n_features):
                weak.append(tid)
        return ObjectFrameResult(self.estimates(objects, frame.index), n_matches, weak)

    # --------------------------------------------------------------- keyframes
    def on_keyframe(self, frame: Frame, kf_id: int, objects: ObjectMap, weak: list[int]) -> None:
        """A keyframe was made from `frame`: its object observations join BA windows, and each weakly
        tracked object (III-D; with objects.kf_points_all_objects every one) gains new points from its instance's free
        close keypoints."""
        used = [o.kp_idx for tr in objects.tracks.values() if (o := tr.at_frame(frame.index)) is not None]
        free = dynamic_keypoints(frame)
        if used:
            free[np.concatenate(used)] = False
        for tr in objects.tracks.values():
            obs = tr.at_frame(frame.index)
            if obs is None:
                continue
            obs.kf_id = kf_id
            is_weak = tr.track_id in weak
            if not (is_weak or self.cfg.kf_points_all_objects):
                continue
            kp = self._close(frame, np.flatnonzero(free & (frame.instance_id == obs.instance_id)))
            if len(kp) == 0:
                continue
            T_o_w = inverse(obs.T_w_o)
            X_o = self._world_points(frame, kp) @ T_o_w[:3, :3].T + T_o_w[:3, 3]
            old = objects.points.X_o[obs.pt_ids]
            if len(old):
                ok = np.linalg.norm(X_o - np.median(old, axis=0), axis=1) <= self.cfg.max_point_spread_m
                kp, X_o = kp[ok], X_o[ok]
            new = objects.add_points(tr.track_id, X_o, frame.keypoints.desc[kp], self._depth_weight(frame, kp))
            objects.points.coverage[new] = not is_weak
            obs.kp_idx = np.r_[obs.kp_idx, kp]
            obs.pt_ids = np.r_[obs.pt_ids, new]
            free[kp] = False
