"""Object-trajectory metrics of `dynaslam2 eval` (the `objects.*` keys of DESIGN.md; paper IV-B, Table IV).

Definitions (parameters in ObjectEvalConfig):
- A GT object counts at a frame ("eligible") when it is listed in the sequence's GT at that frame
  (our sequences list objects with at least one visible pixel), its box centre lies within
  `max_range_m` of the camera, its visible fraction is >= `min_visible_fraction` (unknown passes), its
  KITTI occlusion level is <= `max_occlusion`, its truncation is <= `max_truncation` (unknown passes)
  and its 2D box is >= `min_box_height_px` high. The defaults score every listed object within 30 m,
  however small or hidden; `PAPER_PROTOCOL` adds the selection of the paper's Table IV (IV-B:
  detections "neither occluded nor truncated, and whose height is at least 40 pixels"). A GT track is
  scored when it is eligible in at least `min_visible_frames` frames; its eligible frames are its
  "visible frames".
- Overlap of an estimated object with a GT object at a frame: when the estimate carries an instance id
  (and `use_instance_ids`), that id equals the GT's MOTS id `class_id*1000 + track_id`; otherwise the IoU
  of the two 2D boxes is >= `min_iou` (the paper's 25 %).
- Matching: each GT track is matched on its own to the estimated track that overlaps it in the most
  visible frames (ties: lower track id), provided that is at least `min_matched_frames`; several GT
  tracks may match the same estimated track. Its matched frames are the visible frames where that
  estimated track overlaps it; tp_ratio = matched frames / visible frames (0 when unmatched).
- Offset: the estimated frame (centroid of the first points, world axes) is rigidly attached to the
  body but is not the GT box frame: T_w_o_est(t) = T_w_o_gt(t) @ T_off. Estimated once per track by least
  squares over the matched frames: d = mean_t R_gt(t)^T (p_est(t) - p_gt(t)) (exact minimizer of
  sum |p_est - p_gt - R_gt d|^2) and R_off = the chordal mean of R_gt(t)^T R_est(t) (SVD projection).
- ate_m: RMSE over the matched frames of |p_est - (p_gt + R_gt d)|, both in the sequence world (left camera
  at frame 0) as written, so it includes the ego drift. ate_cam_m: the same after re-expressing each
  estimate through the GT camera, T_w_c_gt @ inv(T_w_c_est) @ T_w_o_est (the object relative to the
  camera, without ego error). Without GT camera poses (KITTI tracking) GT objects are camera-frame
  poses and both compare inv(T_w_c_est) @ T_w_o_est with them.
- rpe_t (m), rpe_r (deg): evo's RPE (eval.trajectory.rpe) between the estimates P(t) and the GT poses of
  the estimated frame Q(t) = T_w_o_gt(t) @ T_off, over the pairs (t, t+1) of matched frames, RMSE.
- id_switches: along the visible frames where some estimate overlaps the GT track, the best overlapping
  estimate (instance match first, then IoU, then more points) changes while the GT was eligible in every
  frame in between; reid_switches: it changes across frames where the GT was not eligible (occluded,
  out of view or beyond range). id_switch_frames / reid_switch_frames: each switch as [frame, previous
  estimated id, new estimated id], the frame being the first of the new id. max_gap_s: the longest time
  between two consecutive visible frames of the track that are not adjacent (0 when it is visible in one run).
- short_gaps: the gaps of at most `short_gap_s` between two consecutive visible frames that are not
  adjacent, where some estimate overlaps the GT in the run of adjacent visible frames before the gap and in
  the run after it; short_gaps_kept: those where the best overlapping estimate of the last such frame before
  the gap and of the first one after it are the same (issue 4: "an object that is occluded for <= 1 s keeps its
  track id"; with `UNOCCLUDED_PROTOCOL` a gap is a run of frames where the object is occluded, hidden
  or beyond range).
- per_track.<gt_id>: ate_m, ate_cam_m, rpe_t, rpe_r, tp_ratio, matched_est_id, visible_frames,
  matched_frames, offset_m (|d|), id_switches, reid_switches, id_switch_frames, reid_switch_frames, max_gap_s,
  short_gaps, short_gaps_kept (null where undefined).
- Totals: ate_rmse_m, ate_cam_rmse_m, rpe_*: means over the matched tracks (rpe over those with a
  pair); tp_ratio: mean over the scored GT tracks; id_switches, reid_switches, short_gaps,
  short_gaps_kept: sums.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from dynaslam2.classes import CLASS_IDS, INSTANCE_CLASS_FACTOR
from dynaslam2.errors import InputError
from dynaslam2.eval.trajectory import rpe
from dynaslam2.geometry.se3 import inverse
from dynaslam2.io.sequence import Sequence
from dynaslam2.io.types import ObjectEstimate, ObjectState
from dynaslam2.time_windows import within


@dataclass(frozen=True)
class ObjectEvalConfig:
    """Thresholds of the object evaluation (see the module docstring for how each is used)."""

    max_range_m: float = 30.0  # issue 4: "objects within 30 m"
    min_visible_frames: int = 10  # 1 s at 10 Hz
    min_matched_frames: int = 3
    min_iou: float = 0.25  # paper IV-B
    use_instance_ids: bool = True
    min_visible_fraction: float = 0.0
    min_box_height_px: float = 0.0
    max_occlusion: int = 3  # KITTI levels: 0 fully visible, 1 partly, 2 largely occluded, 3 unknown
    max_truncation: float = 1.0
    short_gap_s: float = 1.0  # issue 4: an object occluded for <= 1 s keeps its id


# Paper IV-B (Table IV): objects neither occluded nor truncated and at least 40 px high (within 30 m here).
PAPER_PROTOCOL = ObjectEvalConfig(min_box_height_px=40.0, max_occlusion=0, max_truncation=0.0)
# Issue 4's id criteria: no id switch while the object is unoccluded (KITTI occlusion level 0, within 30 m,
# truncated or not), and the same id across occlusions of <= 1 s (short_gaps_kept / short_gaps).
UNOCCLUDED_PROTOCOL = ObjectEvalConfig(max_occlusion=0)


def _box_areas(boxes_a: np.ndarray, boxes_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, M) intersection areas, (N, 1) areas of `boxes_a`, (1, M) areas of `boxes_b` (left, top, right, bottom)."""
    a = np.asarray(boxes_a, dtype=float).reshape(-1, 1, 4)
    b = np.asarray(boxes_b, dtype=float).reshape(1, -1, 4)
    w = np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0])
    h = np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1])
    inter = np.clip(np.nan_to_num(w), 0.0, None) * np.clip(np.nan_to_num(h), 0.0, None)
    return inter, (a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1]), (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])


def box_iou(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """(N, 4) x (M, 4) boxes (left, top, right, bottom) -> (N, M) IoU; NaN boxes give 0."""
    inter, area_a, area_b = _box_areas(boxes_a, boxes_b)
    union = np.nan_to_num(area_a + area_b - inter)
    return np.where(union > 0.0, inter / np.where(union > 0.0, union, 1.0), 0.0)


def box_covered(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """(N, 4) x (M, 4) boxes -> (N, M) fraction of each box of `boxes_b` that lies inside each box of `boxes_a`;
    NaN or empty boxes give 0."""
    inter, _, area_b = _box_areas(boxes_a, boxes_b)
    area_b = np.nan_to_num(np.broadcast_to(area_b, inter.shape))
    return np.where(area_b > 0.0, inter / np.where(area_b > 0.0, area_b, 1.0), 0.0)


def frame_offset(T_est: np.ndarray, T_gt: np.ndarray) -> np.ndarray:
    """Least-squares constant offset T_off (4x4) with T_est(t) ~ T_gt(t) @ T_off over (N, 4, 4) pairs.

    Translation d = mean R_gt^T (p_est - p_gt); rotation R_off = chordal mean of R_gt^T R_est.
    """
    R_gt, p_gt = T_gt[:, :3, :3], T_gt[:, :3, 3]
    d = np.einsum("nji,nj->ni", R_gt, T_est[:, :3, 3] - p_gt).mean(axis=0)
    U, _, Vt = np.linalg.svd(np.einsum("nji,njk->ik", R_gt, T_est[:, :3, :3]))
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    T_off = np.eye(4)
    T_off[:3, :3], T_off[:3, 3] = U @ S @ Vt, d
    return T_off


def _contiguous_runs(frames: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the runs of consecutive frame numbers in a sorted array."""
    breaks = np.flatnonzero(np.diff(frames) != 1) + 1
    return np.split(np.arange(len(frames)), breaks)


def track_errors(T_est: np.ndarray, T_gt: np.ndarray, frames: np.ndarray) -> dict:
    """Errors of one estimated object trajectory against its GT track at the (sorted) `frames`.

    Returns T_off, ate_m, errors_m (per frame), rpe_t (m) and rpe_r (deg) RMSE over the pairs of
    adjacent frames (None without a pair), and pairs.
    """
    T_est, T_gt = np.asarray(T_est, dtype=float), np.asarray(T_gt, dtype=float)
    T_off = frame_offset(T_est, T_gt)
    errors = np.linalg.norm(T_est[:, :3, 3] - (T_gt[:, :3, 3] + T_gt[:, :3, :3] @ T_off[:3, 3]), axis=1)
    Q = T_gt @ T_off
    t_err, r_err = [], []
    for run in _contiguous_runs(np.asarray(frames)):
        if len(run) > 1:
            rel = rpe(T_est[run], Q[run], delta=1)
            t_err.append(rel["t_errors_m"])
            r_err.append(rel["r_errors_deg"])
    t_err = np.concatenate(t_err) if t_err else np.zeros(0)
    r_err = np.concatenate(r_err) if r_err else np.zeros(0)
    return {
        "T_off": T_off,
        "ate_m": float(np.sqrt(np.mean(errors**2))),
        "errors_m": errors,
        "rpe_t": float(np.sqrt(np.mean(t_err**2))) if len(t_err) else None,
        "rpe_r": float(np.sqrt(np.mean(r_err**2))) if len(r_err) else None,
        "pairs": int(len(t_err)),
    }


def _eligible(obj: ObjectState, T_c_w_gt: np.ndarray, config: ObjectEvalConfig) -> bool:
    range_m = np.linalg.norm(T_c_w_gt[:3, :3] @ np.asarray(obj.T_w_o, dtype=float)[:3, 3] + T_c_w_gt[:3, 3])
    if range_m > config.max_range_m or obj.visible_fraction < config.min_visible_fraction:
        return False
    if obj.occlusion > config.max_occlusion or obj.truncation > config.max_truncation:
        return False
    if config.min_box_height_px > 0.0:
        return obj.box2d is not None and obj.box2d[3] - obj.box2d[1] >= config.min_box_height_px
    return True


def _frame_overlaps(gts: list[ObjectState], ests: list[ObjectEstimate],
                    config: ObjectEvalConfig) -> tuple[np.ndarray, np.ndarray]:
    """(G, E) overlap flags and preference scores (instance match + IoU) of one frame."""
    nan_box = (np.nan,) * 4
    gt_boxes = np.array([g.box2d if g.box2d is not None else nan_box for g in gts], dtype=float).reshape(-1, 4)
    est_boxes = np.array([e.box2d if e.box2d is not None else nan_box for e in ests], dtype=float).reshape(-1, 4)
    iou = box_iou(gt_boxes, est_boxes)
    gt_mots = np.array([CLASS_IDS.get(g.cls, 0) * INSTANCE_CLASS_FACTOR + int(g.track_id) for g in gts])
    est_inst = np.array([int(e.instance_id) for e in ests])
    by_instance = np.broadcast_to(config.use_instance_ids & (est_inst != 0), iou.shape)
    same_instance = gt_mots[:, None] == est_inst[None, :]
    overlap = np.where(by_instance, same_instance, iou >= config.min_iou)
    return overlap, iou + same_instance


def evaluate_object_tracks(
    gt_objects: list[list[ObjectState]],
    T_w_c_gt: np.ndarray | None,
    timestamps: np.ndarray,
    est_objects: list[list[ObjectEstimate]],
    T_w_c_est: np.ndarray,
    config: ObjectEvalConfig = ObjectEvalConfig(),
) -> dict:
    """The `objects` metrics section from per-frame GT objects and estimates (module docstring)."""
    n = len(gt_objects)
    if len(est_objects) != n or len(T_w_c_est) != n or len(timestamps) != n:
        raise ValueError(f"evaluate_object_tracks: {n} GT frames but {len(est_objects)} estimate frames, "
                         f"{len(T_w_c_est)} camera poses, {len(timestamps)} timestamps")
    T_w_c_est = np.asarray(T_w_c_est, dtype=float)
    # The frame GT objects are expressed in, and the estimates moved into it ("world" and camera-relative).
    T_w_c_ref = np.tile(np.eye(4), (n, 1, 1)) if T_w_c_gt is None else np.asarray(T_w_c_gt, dtype=float)
    T_c_w_ref = inverse(T_w_c_ref)
    T_ref_est = T_w_c_ref @ inverse(T_w_c_est)  # estimated world -> GT world through the cameras
    world_as_written = T_w_c_gt is not None

    visible: dict[int, list[int]] = {}  # GT track -> eligible frames
    gt_pose: dict[tuple[int, int], np.ndarray] = {}
    overlaps: dict[tuple[int, int], set[int]] = {}  # (gt, frame) -> overlapping est tracks
    best: dict[tuple[int, int], int] = {}  # (gt, frame) -> preferred overlapping est track
    est_pose: dict[tuple[int, int], np.ndarray] = {}
    for f in range(n):
        ests = est_objects[f]
        for e in ests:
            est_pose[e.track_id, f] = np.asarray(e.T_w_o, dtype=float)
        gts = [g for g in gt_objects[f] if _eligible(g, T_c_w_ref[f], config)]
        if not gts:
            continue
        overlap, score = _frame_overlaps(gts, ests, config) if ests else (None, None)
        points = np.array([e.n_points for e in ests])
        ids = np.array([e.track_id for e in ests])
        for k, g in enumerate(gts):
            gid = int(g.track_id)
            visible.setdefault(gid, []).append(f)
            gt_pose[gid, f] = np.asarray(g.T_w_o, dtype=float)
            hits = np.flatnonzero(overlap[k]) if ests else np.zeros(0, int)
            if len(hits):
                overlaps[gid, f] = {int(ids[h]) for h in hits}
                order = np.lexsort((ids[hits], -points[hits], -score[k, hits]))
                best[gid, f] = int(ids[hits[order[0]]])

    per_track: dict[str, dict] = {}
    matched_rows = []
    for gid in sorted(visible):
        frames = np.array(visible[gid])
        if len(frames) < config.min_visible_frames:
            continue
        counts = Counter(e for f in frames for e in overlaps.get((gid, f), ()))
        est_id, hits = min(counts.items(), key=lambda kv: (-kv[1], kv[0])) if counts else (None, 0)
        if hits < config.min_matched_frames:
            est_id = None
        row = {"ate_m": None, "ate_cam_m": None, "rpe_t": None, "rpe_r": None, "tp_ratio": 0.0,
               "matched_est_id": est_id, "visible_frames": int(len(frames)), "matched_frames": 0, "offset_m": None}
        if est_id is not None:
            mf = np.array([f for f in frames if est_id in overlaps.get((gid, f), ())])
            T_gt = np.stack([gt_pose[gid, f] for f in mf])
            T_est = np.stack([est_pose[est_id, f] for f in mf])
            T_est_cam = T_ref_est[mf] @ T_est
            world = track_errors(T_est if world_as_written else T_est_cam, T_gt, mf)
            row.update(ate_m=world["ate_m"], ate_cam_m=track_errors(T_est_cam, T_gt, mf)["ate_m"],
                       rpe_t=world["rpe_t"], rpe_r=world["rpe_r"], tp_ratio=len(mf) / len(frames),
                       matched_frames=int(len(mf)), offset_m=float(np.linalg.norm(world["T_off"][:3, 3])))
            matched_rows.append(row)
        row.update(_switches(frames, [best.get((gid, f)) for f in frames], np.asarray(timestamps, dtype=float),
                             config.short_gap_s))
        per_track[str(gid)] = row

    def mean(key: str) -> float | None:
        values = [r[key] for r in matched_rows if r[key] is not None]
        return float(np.mean(values)) if values else None

    rows = per_track.values()
    return {
        "ate_rmse_m": mean("ate_m"),
        "ate_cam_rmse_m": mean("ate_cam_m"),
        "rpe_t_m_per_frame": mean("rpe_t"),
        "rpe_r_deg_per_frame": mean("rpe_r"),
        "tp_ratio": float(np.mean([r["tp_ratio"] for r in rows])) if rows else None,
        "gt_tracks": len(per_track),
        "matched_tracks": len(matched_rows),
        "est_tracks": len({e.track_id for frame in est_objects for e in frame}),
        "id_switches": sum(r["id_switches"] for r in rows),
        "reid_switches": sum(r["reid_switches"] for r in rows),
        "short_gaps": sum(r["short_gaps"] for r in rows),
        "short_gaps_kept": sum(r["short_gaps_kept"] for r in rows),
        "per_track": per_track,
    }


def _switches(frames: np.ndarray, assigned: list[int | None], timestamps: np.ndarray, short_gap_s: float) -> dict:
    """id_switches / reid_switches / max_gap_s / short_gaps / short_gaps_kept of one GT track (module docstring)."""
    position = {int(f): k for k, f in enumerate(frames)}  # rank among the track's eligible frames
    tracked = [(int(f), a) for f, a in zip(frames, assigned) if a is not None]
    id_switch_frames, reid_switch_frames = [], []
    for (f1, a1), (f2, a2) in zip(tracked[:-1], tracked[1:]):
        if a1 != a2:
            kind = id_switch_frames if position[f2] - position[f1] == f2 - f1 else reid_switch_frames
            kind.append([f2, a1, a2])
    # Runs of adjacent eligible frames; a gap lies between two runs, its ends are the last estimate reported in
    # the run before it and the first one in the run after it (a track reported a frame late still counts).
    starts = np.r_[0, np.flatnonzero(np.diff(frames) > 1) + 1, len(frames)]
    runs = [[a for a in assigned[i:j] if a is not None] for i, j in zip(starts[:-1], starts[1:])]
    gaps = [(timestamps[frames[j]] - timestamps[frames[j - 1]], r1[-1] if r1 else None, r2[0] if r2 else None)
            for j, r1, r2 in zip(starts[1:-1], runs[:-1], runs[1:])]
    short = [(a1, a2) for dt, a1, a2 in gaps if within(dt, short_gap_s) and a1 is not None and a2 is not None]
    return {"id_switches": len(id_switch_frames), "reid_switches": len(reid_switch_frames),
            "id_switch_frames": id_switch_frames, "reid_switch_frames": reid_switch_frames,
            "max_gap_s": float(max((dt for dt, _, _ in gaps), default=0.0)),
            "short_gaps": len(short), "short_gaps_kept": sum(a1 == a2 for a1, a2 in short)}


def evaluate_objects(seq: Sequence, est_objects: list[list[ObjectEstimate]], T_w_c_est: np.ndarray,
                     config: ObjectEvalConfig = ObjectEvalConfig()) -> dict:
    """The `objects` metrics of per-frame estimates (e.g. `read_results(RES).objects`) against `seq`'s GT."""
    if len(est_objects) != len(seq):
        raise InputError(f"{len(est_objects)} frames of estimated objects but the sequence {seq.path} has {len(seq)}")
    gt_objects = [seq.gt_objects(i) for i in range(len(seq))]
    return evaluate_object_tracks(gt_objects, seq.gt_T_w_c, seq.timestamps, est_objects, T_w_c_est, config)
