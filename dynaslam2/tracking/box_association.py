"""Instance-to-instance association by 2D boxes (paper III-B: an instance whose box overlaps the box of a recently
seen object of its class continues that object's track), with SORT's motion-compensated boxes (the last box carried by
the object's predicted motion, `predicted_box`, or by its image velocity, `image_extrapolated_box`), SORT's max_age
(the join window counts from the track's newest observation), the frame's instances assigned to the tracks jointly
(SORT's Hungarian assignment), and, where no box overlaps enough, DeepSORT's Mahalanobis gate on the box centre
(`objects.box_gate_chi2`), then a vehicle's predicted 3D extent holding the instance's stereo points
(`objects.extent_min_fraction`), last the gate for the young pedestrian tracks that have no velocity yet. As in
DeepSORT, the confirmed tracks are matched before the tentative ones, and a person's colours enter the cost."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from dynaslam2.classes import VEHICLE_CLASSES
from dynaslam2.config import ObjectsConfig
from dynaslam2.eval.objects import box_covered, box_iou
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse, transform
from dynaslam2.map.frame import Frame
from dynaslam2.map.objects import ObjectMap, ObjectTrack
from dynaslam2.time_windows import within
from dynaslam2.tracking.object_filter import gated, initial_speed_sigma, predict_state


def _hungarian(cost: np.ndarray, ok: np.ndarray) -> list[tuple[int, int]]:
    """The (row, column) pairs of the minimum-`cost` assignment among the allowed pairs `ok` that takes as many of
    them as it can (a forbidden pair costs more than any allowed assignment; SORT's Hungarian assignment)."""
    if not ok.any():
        return []
    forbidden = 1.0 + 2.0 * ok.sum() * np.abs(cost[ok]).max()  # > any two allowed assignments' difference
    rows, cols = linear_sum_assignment(np.where(ok, cost, forbidden))
    return [(k, t) for k, t in zip(rows.tolist(), cols.tolist()) if ok[k, t]]


def last_seen_points(objects: ObjectMap, track: ObjectTrack) -> np.ndarray:
    """Ids of the points of the track's newest observation that has any (culled since or not: the part of the object
    last seen), else of its living points."""
    for obs in reversed(track.observations):
        if len(obs.pt_ids):
            return obs.pt_ids
    return objects.points.of_track(track.track_id)


def reanchored_pose(objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray, X_w: np.ndarray,
                    spread_m: float | None) -> np.ndarray | None:
    """The predicted pose translated so that the median of an instance's world points `X_w` lands on the median of
    the track's points last seen (`last_seen_points`), when that median lies beyond `spread_m` of their box (object
    frame: the prediction ran off, or the points are not the track's object; None: always); None when it lies within,
    or without points. (All living points: a person's three points placed 10 m off its body long before, never in
    view again and so never culled, outlived those it was last seen with, and the re-anchor put its track 10 m off,
    crossing s1 f98.)"""
    X_o = objects.points.X_o[last_seen_points(objects, track)]
    if not len(X_o) or not len(X_w):
        return None
    R, t = T_w_o_pred[:3, :3], T_w_o_pred[:3, 3]
    median_new = np.median((X_w - t) @ R, axis=0)
    outside = np.maximum(X_o.min(axis=0) - median_new, 0.0) + np.maximum(median_new - X_o.max(axis=0), 0.0)
    if spread_m is not None and np.linalg.norm(outside) <= spread_m:
        return None
    T_w_o = T_w_o_pred.copy()
    T_w_o[:3, 3] = t + R @ (median_new - np.median(X_o, axis=0))
    return T_w_o


def implausible_jump(track: ObjectTrack, timestamp: float, p_w: np.ndarray, cfg: ObjectsConfig) -> bool:
    """Whether the track, measured within join_max_gap_s of `timestamp`, cannot be at `p_w` then: its filter's
    prediction excludes it (`gated` at reanchor_gate_nis, `p_w` exact but for the position floor)."""
    measured = [o.timestamp for o in track.observations if o.measured]
    exact = np.eye(3) * 1e12
    return bool(measured and within(timestamp - measured[-1], cfg.join_max_gap_s)
                and gated(track, timestamp - track.last.timestamp, p_w, lambda: exact, cfg, nis=cfg.reanchor_gate_nis))


def _extent(objects: ObjectMap, track: ObjectTrack) -> tuple[np.ndarray, np.ndarray] | None:
    """The track's 3D extent in its object frame: the 5th and 95th percentile per axis of its points (None without
    points)."""
    X_o = objects.points.X_o[objects.points.of_track(track.track_id)]
    return (np.percentile(X_o, 5, axis=0), np.percentile(X_o, 95, axis=0)) if len(X_o) else None


def instance_boxes(instances: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(K, 4) boxes (left, top, right, bottom) in px of the masks of instance ids `ids` (NaN if absent)."""
    boxes = np.full((len(ids), 4), np.nan)
    if len(ids) == 0:
        return boxes
    rows, cols = np.nonzero(np.isin(instances, ids))
    lab = instances[rows, cols].astype(np.int64)
    order = np.argsort(lab, kind="stable")
    lab, rows, cols = lab[order], rows[order], cols[order]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]]) if len(lab) else np.zeros(0, np.int64)
    if len(starts) == 0:
        return boxes
    k = np.searchsorted(ids, lab[starts])
    boxes[k] = np.column_stack([np.minimum.reduceat(cols, starts), np.minimum.reduceat(rows, starts),
                                np.maximum.reduceat(cols, starts), np.maximum.reduceat(rows, starts)])
    return boxes


def keypoint_boxes(frame: Frame, dyn: np.ndarray, inst_ids: np.ndarray) -> np.ndarray:
    """Boxes of each instance's keypoints (when the instance image is not given)."""
    boxes = np.full((len(inst_ids), 4), np.nan)
    for k, inst in enumerate(inst_ids.tolist()):
        uv = frame.keypoints.uv[dyn & (frame.instance_id == inst)]
        boxes[k] = [*uv.min(0), *uv.max(0)]
    return boxes


class BoxAssociation:
    """Box association of a frame's unclaimed instances with the tracks not seen in it (state in the tracks)."""

    def __init__(self, cfg: ObjectsConfig, camera: StereoCamera) -> None:
        self.cfg = cfg
        self.camera = camera

    def predicted_box(self, track: ObjectTrack, frame: Frame, T_w_o_pred: np.ndarray,
                      objects: ObjectMap) -> np.ndarray | None:
        """The object's last 2D box carried into `frame` (instance-to-instance association with motion
        compensation), clipped to the image: it follows the mean projection of the object points of the last
        observation (X_o, in `objects`) from the last pose and camera to the predicted
        pose and this camera, and scales by the median ratio of their depths (an approaching object's
        box grows; a turn that changes its outline does not count). With fewer than 3 of the points in
        front of both cameras the object-frame origin moves it; the last box as it was when neither can.
        None without a last box, when the points and the origin are all predicted behind this camera
        (a passed object: its last box as it was would take the instance of the object now there), or when the
        moved box (and a vehicle's predicted 3D extent, `_extent_box`) lies wholly outside the image (an object that
        has left the view: its last box, a sliver at the border, took the sliver of the next object leaving there,
        crossing s90 f135). A vehicle's moved box outside the image while its extent is not (the part last seen has
        left, the rest is still in view: crossing s77 f37, a car passing at the left border) is clipped to the
        border: the track stays a candidate, which its extent ("extent" stage of `assign`) or its last box may join.
        Not a person's: no stage joins by a person's extent, and its last box took the sliver of the next person
        leaving there (crossing s97 f128)."""
        last = track.last
        if last.box2d is None:
            return None
        box = np.asarray(last.box2d, dtype=float)
        X_o = objects.points.X_o[last.pt_ids]
        motion = None
        if last.T_c_w is not None:
            if not np.any(transform(frame.T_c_w @ T_w_o_pred, np.vstack([X_o, np.zeros((1, 3))]))[:, 2] > 1e-3):
                return None
            motion = self._image_motion(track, frame, T_w_o_pred, X_o, 3)
            if motion is None:
                motion = self._image_motion(track, frame, T_w_o_pred, np.zeros((1, 3)), 1)
        if motion is not None:
            uv_last, uv_pred, scale = motion
            box = np.r_[uv_pred, uv_pred] + scale * (box - np.r_[uv_last, uv_last])
        if not self._in_image(box):
            extent = self._extent_box(objects, track, frame, T_w_o_pred) if track.cls in VEHICLE_CLASSES else None
            if extent is None or not self._in_image(extent):
                return None
        return np.clip(box, 0.0, np.array([self.camera.width - 1, self.camera.height - 1] * 2, dtype=float))

    def _in_image(self, box: np.ndarray) -> bool:
        """Whether `box` (u_min, v_min, u_max, v_max) overlaps the image."""
        return bool(np.all(box[:2] <= [self.camera.width - 1, self.camera.height - 1]) and np.all(box[2:] >= 0.0))

    def _extent_box(self, objects: ObjectMap, track: ObjectTrack, frame: Frame, T_w_o_pred: np.ndarray
                    ) -> np.ndarray | None:
        """The image box of the track's 3D extent (`_extent`, without extent_margin_m) at the predicted pose: of its
        corners in front of the camera, grown by the prediction's uncertainty (`_prediction_margin_px`); None
        without points or with every corner behind the camera."""
        extent = _extent(objects, track)
        if extent is None:
            return None
        corners = np.stack(np.meshgrid(*zip(*extent), indexing="ij"), axis=-1).reshape(-1, 3)
        X_c = transform(frame.T_c_w @ T_w_o_pred, corners)
        X_c = X_c[X_c[:, 2] > 1e-3]
        if not len(X_c):
            return None
        uv = self.camera.project(X_c)
        margin = self._prediction_margin_px(track, frame, float(X_c[:, 2].mean()))
        return np.r_[uv.min(axis=0) - margin, uv.max(axis=0) + margin]

    def _prediction_margin_px(self, track: ObjectTrack, frame: Frame, depth: float) -> float:
        """The image distance (px) within which the position filter's prediction at `frame` (`predict_state`) puts
        the object, at `depth`: the largest position sigma seen there, times sqrt(box_gate_chi2) (0 without the
        filter's state). A prediction run off by a few px must not tell a car at the image border that it has left
        (crossing s99 f42: its extent predicted 2 px outside the image at a sigma of 7 px, and a new track took the
        car)."""
        if not (self.cfg.filter and track.state_mean is not None):
            return 0.0
        P = predict_state(track, frame.timestamp - track.last.timestamp, self.cfg)[1][:3, :3]
        sigma_m = float(np.sqrt(np.linalg.eigvalsh(P)[-1]))
        return float(np.sqrt(self.cfg.box_gate_chi2)) * self.camera.fx * sigma_m / depth

    def image_extrapolated_box(self, track: ObjectTrack, timestamp: float) -> np.ndarray | None:
        """The last 2D box moved on to `timestamp` at the image velocity of the track's boxes since its observation
        box_velocity_window_s before the last one (SORT's constant-velocity box). Per image axis the box edge that
        moved least gives the motion: an occluder or the image border clips the other edge, which then moves with
        it. None without such an earlier box."""
        last = track.last
        if last.box2d is None:
            return None
        earlier = None  # the oldest boxed observation within the window, searched back from the newest
        for o in reversed(track.observations):
            if not within(last.timestamp - o.timestamp, self.cfg.box_velocity_window_s):
                break
            if o is not last and o.box2d is not None:
                earlier = o
        if earlier is None:
            return None
        box = np.asarray(last.box2d, dtype=float)
        moved = (box - np.asarray(earlier.box2d, dtype=float)).reshape(2, 2)  # rows: min, max corner; columns: u, v
        per_s = moved[np.argmin(np.abs(moved), axis=0), [0, 1]] / (last.timestamp - earlier.timestamp)
        return box + np.tile(per_s * (timestamp - last.timestamp), 2)

    def _image_motion(self, track: ObjectTrack, frame: Frame, T_w_o_pred: np.ndarray, X_o: np.ndarray,
                      min_points: int) -> tuple[np.ndarray, np.ndarray, float] | None:
        """(mean pixel in the last observation, mean pixel at the predicted pose in `frame`, median
        depth ratio last / predicted) of the object-frame points `X_o` in front of both cameras; None
        with fewer than `min_points` of them."""
        last = track.last
        X_c_last = transform(last.T_c_w @ last.T_w_o, X_o)
        X_c_pred = transform(frame.T_c_w @ T_w_o_pred, X_o)
        front = (X_c_last[:, 2] > 1e-3) & (X_c_pred[:, 2] > 1e-3)
        if np.count_nonzero(front) < min_points:
            return None
        X_c_last, X_c_pred = X_c_last[front], X_c_pred[front]
        return (self.camera.project(X_c_last).mean(axis=0), self.camera.project(X_c_pred).mean(axis=0),
                float(np.median(X_c_last[:, 2] / X_c_pred[:, 2])))  # image size ~ 1 / depth

    def overlap(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray,
                box: np.ndarray) -> float:
        """The IoU of `box` with the track's last box (`_last_box`) or its predicted box, the larger (0 for a NaN
        box)."""
        if not np.all(np.isfinite(box)):
            return 0.0
        moved = self.predicted_box(track, frame, T_w_o_pred, objects)
        track_boxes = [self._last_box(track, frame.timestamp)] + ([moved] if moved is not None else [])
        return float(box_iou(box[None], np.array(track_boxes, dtype=float))[0].max())

    def touches(self, frame: Frame, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray,
                box: np.ndarray) -> bool:
        """Whether `box` overlaps the track's last box or its predicted box at all (`overlap`): a vote whose pose
        failed joins only a track that could be there (a false vote took a bus leaving at the right border to an
        instance entering at the left)."""
        return self.overlap(frame, objects, track, T_w_o_pred, box) > 0

    def assign(self, frame: Frame, objects: ObjectMap, tracks: list[ObjectTrack], pred: dict[int, np.ndarray],
               boxes: np.ndarray, classes: list[str], X_w: list[np.ndarray], looks: dict[int, np.ndarray] | None,
               max_gap_s: np.ndarray, coasting: np.ndarray, stages: tuple[str, ...]) -> list[ObjectTrack | None]:
        """The track each instance box of `boxes` (class `classes`) joins, or None: a joint assignment of the boxes to
        the `tracks` of their class observed within each box's `max_gap_s` ((K,) s; measured or box-joined: SORT's
        max_age counts from the newest matched detection) whose predicted box is not passed behind the camera
        (instance-to-instance association, III-B) and whose appearance gallery holds the instance's colour histogram
        within appearance_max_distance (`looks`: per track id, the (K,) gallery distances of the boxes' instances, NaN
        not judged; None: appearance off). SORT's Hungarian assignment (`_hungarian`) in DeepSORT's cascade of
        `stages`, each over the boxes and tracks the earlier ones left, first for the confirmed tracks (>=
        min_output_observations observations), then for the tentative ones (DeepSORT's order: a track begun on an
        object's partial view a frame ago cannot outbid the object's own track); no stage joins a vehicle track to an
        instance whose stereo points lie outside its predicted 3D extent and in another candidate's
        (`_in_another_extent`):
        "moved": by the overlap of each track's last box moved by its predicted image motion (`predicted_box`;
        `_join_overlap` >= join_iou), so that the last box of an object that has left where this one is now cannot
        take it; ranked by the IoU less the gallery distance (DeepSORT's appearance in the cost: a neighbour's box
        over a person's predicted one does not outbid its own, partly hidden one);
        "box": by that or the overlap of its last box (`_last_box`: a wrong velocity, or a near object whose origin
        projects off its visible part, moves the box wrong), ranked alike; not by the last box of a track that has
        left by an image border (`_left_by_border`, objects.border_exit_drops_last_box);
        "gate": by the Mahalanobis distance (`_gate_distance` <= box_gate_chi2) to a velocity-known track whose
        moved box overlaps the instance's (the overlap bounds the gate where the projected covariance is large: a
        car passing the camera, a box clipped to the image border);
        "extent": by the fraction of the instance's stereo points `X_w` inside a velocity-known vehicle track's
        predicted 3D extent, its length completed when its last box was cut by a side image border
        (`_length_completed`; `extent_fraction` >= extent_min_fraction, or >= join_owner_extent_fraction for the track
        whose extent held an instance vetoed from another, objects.join_vetoed_to_owner; a pedestrian's grown extent
        holds its neighbour);
        "young": likewise to a track without a velocity (its 3D prediction stands still) whose `_last_box` overlaps
        the instance's, when its class has a speed prior tighter than initial_speed_sigma (`initial_speed_sigma`:
        pedestrians) for its filter to start from;
        "appearance": by the distance of the instance's histogram to a person track's gallery (<=
        appearance_reid_distance) within the Mahalanobis gate of its predicted box (re-identification of a track
        lost beyond the box window). A stage named "coast-" + stage is that stage over the `coasting` boxes
        (instances with too few keypoints to measure a pose or hold points), the others over the rest: an object's
        mostly hidden instance whose box overlaps the track's moved box keeps it from a farther object's instance
        that only overlaps its last box (crossing s47), but not from the object's own instance with enough
        keypoints that overlaps its moved box less than a neighbour's sliver does."""
        cfg = self.cfg
        joined: list[ObjectTrack | None] = [None] * len(boxes)
        if not len(boxes):
            return joined
        recent = [tr for tr in tracks if within(frame.timestamp - tr.last.timestamp, max_gap_s.max())]
        moved = [self.predicted_box(tr, frame, pred[tr.track_id], objects) for tr in recent]
        recent, moved = [tr for tr, b in zip(recent, moved) if b is not None], [b for b in moved if b is not None]
        if not recent:
            return joined
        moved = np.array(moved)
        last = np.array([self._last_box(tr, frame.timestamp) for tr in recent])
        open_box = np.all(np.isfinite(boxes), axis=1)
        free = open_box[:, None] & (np.array(classes)[:, None] == np.array([tr.cls for tr in recent])[None])
        free &= within(np.array([frame.timestamp - tr.last.timestamp for tr in recent])[None], max_gap_s[:, None])
        look = np.zeros(free.shape) if looks is None else np.array([looks[tr.track_id] for tr in recent]).T
        free &= ~(look > cfg.appearance_max_distance)
        iou_moved, iou_last = self._join_overlap(boxes, moved), self._join_overlap(boxes, last)
        if cfg.border_exit_drops_last_box:
            iou_last[:, self._left_by_border(recent, moved, last)] = 0.0
        touching = (iou_moved > 0) | (iou_last > 0)
        vetoed, owners = self._in_another_extent(objects, recent, pred, X_w, free & touching)
        free &= ~vetoed & ~self._jumps(frame, objects, recent, pred, X_w, free & touching)

        def score(stage: str, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
            """(cost, allowed) of `stage` over the candidate pairs `cand` (K, T); None: the stage is off."""
            if stage in ("moved", "box"):
                iou = iou_moved if stage == "moved" else np.maximum(iou_moved, iou_last)
                cost, ok = np.nan_to_num(look) - iou, iou >= cfg.join_iou
            elif stage == "extent":
                cost = np.zeros(cand.shape)
                if cfg.extent_min_fraction > 0:
                    for t in np.flatnonzero(cand.any(axis=0)):
                        if recent[t].velocity_known and recent[t].cls in VEHICLE_CLASSES:
                            rows = np.flatnonzero(cand[:, t])
                            cost[rows, t] = -self.extent_fraction(objects, recent[t], pred[recent[t].track_id],
                                                                  [X_w[k] for k in rows], complete_length=True)
                ok = (cost < 0) & ((-cost >= cfg.extent_min_fraction) | owners & cfg.join_vetoed_to_owner)
            elif stage == "appearance":
                cost = np.full(cand.shape, np.inf)
                for t in np.flatnonzero(cand.any(axis=0)):
                    tr, rows = recent[t], np.flatnonzero(cand[:, t])
                    if tr.appearance and tr.state_mean is not None:
                        d2 = self._gate_distance(frame, tr, pred[tr.track_id], moved[t], boxes[rows])
                        cost[rows, t] = np.where(d2 <= cfg.box_gate_chi2, looks[tr.track_id][rows], np.inf)
                ok = cost <= cfg.appearance_reid_distance
            elif stage not in ("gate", "young"):
                raise ValueError(f"unknown box association stage {stage!r}")
            elif cfg.box_gate_chi2 > 0 and cfg.filter:
                young = stage == "young"
                track_box, overlap = (last, iou_last) if young else (moved, iou_moved)
                cost = np.full(cand.shape, np.inf)
                for t in np.flatnonzero(cand.any(axis=0)):
                    tr, rows = recent[t], cand[:, t] & (overlap[:, t] > 0)
                    if rows.any() and tr.state_mean is not None and (
                            not tr.velocity_known and initial_speed_sigma(tr.cls, cfg) < cfg.initial_speed_sigma
                            if young else tr.velocity_known):
                        cost[rows, t] = self._gate_distance(frame, tr, pred[tr.track_id], track_box[t], boxes[rows])
                ok = cost <= cfg.box_gate_chi2
            else:
                return None
            return cost, ok

        confirmed = np.array([len(tr.observations) >= cfg.min_output_observations for tr in recent])
        for group in (confirmed, ~confirmed):
            for stage in stages:
                coast = stage.startswith("coast-")
                cand = free & group[None] & (coasting if coast else ~coasting)[:, None]
                scored = score(stage.removeprefix("coast-"), cand)
                if scored is not None:
                    for k, t in _hungarian(scored[0], cand & scored[1]):
                        joined[k] = recent[t]
                        free[k, :] = False
                        free[:, t] = False
        return joined

    def _in_another_extent(self, objects: ObjectMap, tracks: list[ObjectTrack], pred: dict[int, np.ndarray],
                           X_w: list[np.ndarray], cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, T) the candidate pairs `cand` that no box stage joins, and the pairs the "extent" stage joins at
        join_owner_extent_fraction. The first: an instance with >= min_inliers stereo points `X_w` of which less than
        join_min_extent_fraction lie in a velocity-known vehicle track's predicted 3D extent (`extent_fraction`),
        while >= join_owner_extent_fraction lie in another candidate track's (crossing s120 f82: a car's track,
        predicted 25.5 m away, took by its moved box the instance of a nearer car at 19.4 m that its own track's
        extent held, and the two cars swapped tracks). The second: that other track and the vetoed instance (the
        nearer car's track, its moved box off and its extent holding 0.61 of the points, then lost its car)."""
        cfg = self.cfg
        if cfg.join_min_extent_fraction <= 0:
            return np.zeros(cand.shape, dtype=bool), np.zeros(cand.shape, dtype=bool)
        frac = np.full(cand.shape, np.nan)  # NaN: not judged (no vehicle track with a velocity, too few points)
        for t in np.flatnonzero(cand.any(axis=0)):
            tr = tracks[t]
            rows = [k for k in np.flatnonzero(cand[:, t]) if len(X_w[k]) >= cfg.min_inliers]
            if rows and tr.velocity_known and tr.cls in VEHICLE_CLASSES:
                frac[rows, t] = self.extent_fraction(objects, tr, pred[tr.track_id], [X_w[k] for k in rows])
        owned = np.nan_to_num(frac) >= cfg.join_owner_extent_fraction
        vetoed = (frac < cfg.join_min_extent_fraction) & (owned.sum(axis=1, keepdims=True) - owned > 0)
        return vetoed, owned & vetoed.any(axis=1, keepdims=True)

    def _jumps(self, frame: Frame, objects: ObjectMap, tracks: list[ObjectTrack], pred: dict[int, np.ndarray],
               X_w: list[np.ndarray], cand: np.ndarray) -> np.ndarray:
        """(K, T) the candidate pairs `cand` that no box stage joins: an instance with >= min_inliers stereo points
        `X_w` whose join would re-anchor a track (`reanchored_pose`) by more than reanchor_other_object_m to where
        its filter, measured within join_max_gap_s, cannot be (`implausible_jump`): another object (crossing s80:
        16-25 m shifts of tracks measured 0.5-0.8 s earlier)."""
        cfg = self.cfg
        out = np.zeros(cand.shape, dtype=bool)
        if not np.isfinite(cfg.reanchor_gate_nis):
            return out
        for k, t in zip(*np.nonzero(cand)):
            if len(X_w[k]) >= cfg.min_inliers:
                T_w_o_pred = pred[tracks[t].track_id]
                T_w_o = reanchored_pose(objects, tracks[t], T_w_o_pred, X_w[k], cfg.max_point_spread_m)
                out[k, t] = (T_w_o is not None
                             and np.linalg.norm(T_w_o[:3, 3] - T_w_o_pred[:3, 3]) > cfg.reanchor_other_object_m
                             and implausible_jump(tracks[t], frame.timestamp, T_w_o[:3, 3], cfg))
        return out

    def extent_fraction(self, objects: ObjectMap, track: ObjectTrack, T_w_o_pred: np.ndarray,
                        X_w: list[np.ndarray], complete_length: bool = False) -> np.ndarray:
        """Fraction of each instance's world points `X_w` inside the track's 3D extent (`_extent`; with
        `complete_length`, `_length_completed`) at its predicted pose, grown by extent_margin_m (0 without points)."""
        extent = _extent(objects, track)
        if extent is None:
            return np.zeros(len(X_w))
        if complete_length:
            extent = self._length_completed(track, extent)
        lo, hi = extent[0] - self.cfg.extent_margin_m, extent[1] + self.cfg.extent_margin_m
        T_o_w = inverse(T_w_o_pred)
        return np.array([np.all((P >= lo) & (P <= hi), axis=1).mean() if len(P) else 0.0
                         for P in (transform(T_o_w, X) for X in X_w)])

    def _gate_distance(self, frame: Frame, track: ObjectTrack, T_w_o_pred: np.ndarray, moved: np.ndarray,
                       boxes: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distance of each of `boxes`' centres from the centre of the track's predicted box
        `moved`: the position filter's predicted covariance (`predict_state`) through the projection's Jacobian at the
        predicted object-frame origin, plus (box_gate_size_sigma x each box's width, height)^2; inf behind the
        camera."""
        cfg = self.cfg
        P = predict_state(track, frame.timestamp - track.last.timestamp, cfg)[1][:3, :3]
        X_c = transform(frame.T_c_w, T_w_o_pred[:3, 3][None])
        if X_c[0, 2] <= 1e-3:
            return np.full(len(boxes), np.inf)
        J = self.camera.project_stereo_jacobian(X_c)[0, :2] @ frame.T_c_w[:3, :3]
        box_var = (cfg.box_gate_size_sigma * (boxes[:, 2:] - boxes[:, :2]))**2
        S = J @ P @ J.T + box_var[:, :, None] * np.eye(2)
        r = 0.5 * (boxes[:, :2] + boxes[:, 2:] - moved[:2] - moved[2:])
        d2 = np.einsum("ni,ni->n", r, np.linalg.solve(S, r[:, :, None])[:, :, 0])
        return np.where(np.isfinite(d2), d2, np.inf)

    def _length_completed(self, track: ObjectTrack, extent: tuple[np.ndarray, np.ndarray]
                          ) -> tuple[np.ndarray, np.ndarray]:
        """The vehicle track's extent with its longer horizontal axis (object-frame x or z: the object frame starts
        with the world's axes, the first camera's, y down) grown to its class's length (objects.border_cut_length_m)
        on the side away from the camera of its last observation, when that observation's box was cut by the left
        or right image border: the part beyond the border was never mapped (traffic s39: a stopped van at the left
        border, its points 0.3-3.4 m along its length, reappeared from behind a nearer van by its far end, 3.3-5.9
        m). Otherwise the extent as it is."""
        length = getattr(self.cfg.border_cut_length_m, track.cls, 0.0)
        last = track.last
        if (length <= 0 or last.box2d is None or last.T_c_w is None
                or not (last.box2d[0] <= 0 or last.box2d[2] >= self.camera.width - 1)):
            return extent
        lo, hi = extent[0].copy(), extent[1].copy()
        axis = 0 if hi[0] - lo[0] >= hi[2] - lo[2] else 2
        grow = length - (hi[axis] - lo[axis])
        if grow > 0:
            camera_o = inverse(last.T_c_w @ last.T_w_o)[:3, 3]  # the camera centre in the object frame
            if camera_o[axis] < 0.5 * (lo[axis] + hi[axis]):
                hi[axis] += grow
            else:
                lo[axis] -= grow
        return lo, hi

    def _left_by_border(self, tracks: list[ObjectTrack], moved: np.ndarray, last: np.ndarray) -> np.ndarray:
        """(T,) whether each velocity-known track has left the view by an image border: its moved box was clipped
        from wholly outside the image (zero width or height; `predicted_box` keeps it for its 3D extent still in
        view) and its last box touches the border. Its last box there is where the next object entering appears
        (crossing s99 f77: a van gone by the left border took the van entering there by its last box)."""
        w, h = self.camera.width - 1, self.camera.height - 1
        clipped = (moved[:, 2] <= moved[:, 0]) | (moved[:, 3] <= moved[:, 1])
        at_border = (last[:, 0] <= 0) | (last[:, 1] <= 0) | (last[:, 2] >= w) | (last[:, 3] >= h)
        return clipped & at_border & np.array([tr.velocity_known for tr in tracks], dtype=bool)

    def _last_box(self, track: ObjectTrack, timestamp: float) -> np.ndarray:
        """The track's last box as it was; without a known velocity (its 3D prediction stands still), moved on at
        its image velocity (`image_extrapolated_box`) when it has one."""
        moving = None if track.velocity_known else self.image_extrapolated_box(track, timestamp)
        return np.asarray(track.last.box2d if moving is None else moving, dtype=float)

    def _join_overlap(self, boxes: np.ndarray, track_boxes: np.ndarray) -> np.ndarray:
        """(K, M) IoU of the instance boxes `boxes` with the `track_boxes` (0 for a NaN box), raised to join_iou where
        one of two boxes lies >= join_contain inside the other with an IoU of >= join_iou / 2: an object emerging
        from behind an occluder (its box grows around the partly visible last one) or going behind one (its box
        shrinks inside it)."""
        cfg = self.cfg
        iou = box_iou(boxes, track_boxes)
        if not cfg.join_contain:
            return iou
        inside = np.maximum(box_covered(boxes, track_boxes), box_covered(track_boxes, boxes).T) >= cfg.join_contain
        return np.where(inside & (iou >= 0.5 * cfg.join_iou), np.maximum(iou, cfg.join_iou), iou)
