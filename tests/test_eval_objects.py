"""Object outputs of a run (objects.jsonl, tracks.txt) and the `objects.*` metrics of `dynaslam2 eval`."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

from dynaslam2.classes import CLASS_IDS
from dynaslam2.cli import main
from dynaslam2.errors import InputError
from dynaslam2.eval.objects import (
    PAPER_PROTOCOL, UNOCCLUDED_PROTOCOL, ObjectEvalConfig, box_covered, box_iou, evaluate_object_tracks,
    evaluate_objects, track_errors,
)
from dynaslam2.eval.report import evaluate, format_table
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse, make_pose, se3_exp, so3_exp
from dynaslam2.io import FrameData, ObjectState, SequenceWriter, open_sequence
from dynaslam2.io.kitti import label_to_object_pose, read_tracking_labels
from dynaslam2.io.results import ResultsWriter, read_results
from dynaslam2.io.types import ObjectEstimate, velocity_to_world

W, H = 64, 48
CAMERA = StereoCamera(40.0, 40.0, 31.5, 23.5, 0.5, W, H)
FPS = 10.0
# GT object frame in the OpenCV world: x forward (+z world), y left (-x world), z up (-y world).
R_HEADING_Z = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
DIMS = (4.0, 1.8, 1.5)
# Estimated frame = centroid of the first points with world axes: a constant offset from the GT box frame.
T_OFF_TRUE = make_pose(R_HEADING_Z.T @ so3_exp(np.array([0.0, 0.05, 0.0])), np.array([-1.2, 0.3, 0.2]))


def camera_poses(n: int) -> np.ndarray:
    """The ego drives forward at 5 m/s with a slight yaw."""
    return np.stack([make_pose(so3_exp(np.array([0.0, 0.01 * i, 0.0])), np.array([0.0, 0.0, 0.5 * i]))
                     for i in range(n)])


def gt_track(track_id: int, n: int, start: tuple[float, float, float], speed: float, yaw_rate: float = 0.0):
    """T_w_o (n, 4, 4) of a car driving along world +z at `speed` m/s, turning at `yaw_rate` rad/s."""
    yaw = yaw_rate * np.arange(n) / FPS
    R = so3_exp(np.stack([np.zeros(n), yaw, np.zeros(n)], -1)) @ R_HEADING_Z
    p = np.asarray(start, dtype=float) + np.outer(np.arange(n) / FPS, (0.0, 0.0, speed))
    return make_pose(R, p)


def project_box(T_c_o: np.ndarray, dims=DIMS) -> tuple[float, float, float, float]:
    signs = np.array([[(k >> b & 1) * 2 - 1 for b in range(3)] for k in range(8)], dtype=float)
    X = (0.5 * np.asarray(dims) * signs) @ T_c_o[:3, :3].T + T_c_o[:3, 3]
    u = CAMERA.fx * X[:, 0] / X[:, 2] + CAMERA.cx
    v = CAMERA.fy * X[:, 1] / X[:, 2] + CAMERA.cy
    return float(u.min()), float(v.min()), float(u.max()), float(v.max())


def mots_id(track_id: int, cls: str = "car") -> int:
    return CLASS_IDS[cls] * 1000 + track_id


class Scene:
    """Per-frame GT objects of a few cars; `hidden[track] = frames where it is not listed` (occluded)."""

    def __init__(self, n: int, tracks: dict[int, np.ndarray], hidden: dict[int, range] | None = None):
        self.n = n
        self.T_w_c = camera_poses(n)
        self.tracks = tracks
        self.times = np.arange(n) / FPS
        hidden = hidden or {}
        self.gt = []
        for i in range(n):
            frame = []
            for tid, T_w_o in tracks.items():
                if i in hidden.get(tid, ()):
                    continue
                box = project_box(inverse(self.T_w_c[i]) @ T_w_o[i])
                frame.append(ObjectState(tid, "car", T_w_o[i], np.array([0.0, 0.0, 5.0]), np.zeros(3), DIMS,
                                         box2d=box))
            self.gt.append(frame)

    def estimate(self, assignment: dict[int, dict[int, int]], rng=None, noise_m: float = 0.0,
                 with_instances: bool = True, drift: np.ndarray | None = None) -> tuple[list, np.ndarray]:
        """Estimates from the GT: `assignment[gt][frame] = est track id`; est T_w_o = GT @ T_OFF_TRUE
        (+ noise), in a world moved by `drift[i]` (the estimated camera is drifted alike)."""
        T_w_c_est = self.T_w_c.copy() if drift is None else drift @ self.T_w_c
        est = [[] for _ in range(self.n)]
        for gid, frames in assignment.items():
            for i, eid in frames.items():
                T_w_o = self.tracks[gid][i] @ T_OFF_TRUE
                if noise_m:
                    T_w_o = T_w_o @ se3_exp(np.concatenate([rng.normal(0, noise_m, 3), rng.normal(0, 0.005, 3)]))
                if drift is not None:
                    T_w_o = drift[i] @ T_w_o
                box = project_box(inverse(self.T_w_c[i]) @ self.tracks[gid][i])
                est[i].append(ObjectEstimate(eid, "car", T_w_o, np.array([0.0, 0.0, 5.0]), np.zeros(3), n_points=40,
                                             instance_id=mots_id(gid) if with_instances else 0, box2d=box))
        return est, T_w_c_est


def evaluate_scene(scene: Scene, est, T_w_c_est, **config) -> dict:
    return evaluate_object_tracks(scene.gt, scene.T_w_c, scene.times, est, T_w_c_est, ObjectEvalConfig(**config))


def three_cars(n: int = 30) -> dict[int, np.ndarray]:
    return {1: gt_track(1, n, (1.5, 0.8, 10.0), 6.0, yaw_rate=0.15),
            2: gt_track(2, n, (-3.0, 0.8, 14.0), 4.0),
            3: gt_track(3, n, (7.0, 0.8, 16.0), 5.0, yaw_rate=-0.1)}


# ---------------------------------------------------------------- trajectory errors


def test_constant_offset_is_recovered_and_ate_is_the_noise_level():
    n = 30
    scene = Scene(n, three_cars(n))
    exact, T_w_c_est = scene.estimate({g: {i: 10 + g for i in range(n)} for g in (1, 2, 3)})
    m = evaluate_scene(scene, exact, T_w_c_est)
    assert m["gt_tracks"] == 3 and m["matched_tracks"] == 3 and m["est_tracks"] == 3
    assert m["ate_rmse_m"] < 1e-9 and m["rpe_t_m_per_frame"] < 1e-9 and m["rpe_r_deg_per_frame"] < 1e-5
    for gid in (1, 2, 3):
        row = m["per_track"][str(gid)]
        assert row["matched_est_id"] == 10 + gid and row["tp_ratio"] == 1.0 and row["matched_frames"] == n
        assert row["offset_m"] == pytest.approx(np.linalg.norm(T_OFF_TRUE[:3, 3]), abs=1e-9)
        assert row["id_switches"] == 0 and row["reid_switches"] == 0 and row["max_gap_s"] == 0.0

    sigma = 0.05
    noisy, _ = scene.estimate({g: {i: 10 + g for i in range(n)} for g in (1, 2, 3)}, np.random.default_rng(0), sigma)
    m = evaluate_scene(scene, noisy, T_w_c_est)
    # Isotropic noise sigma per axis: rmse sqrt(3) sigma, less the 3 of 3n dof the offset absorbs.
    expected = sigma * np.sqrt(3.0 * (n - 1) / n)
    assert 0.75 * expected < m["ate_rmse_m"] < 1.25 * expected
    assert m["ate_cam_rmse_m"] == pytest.approx(m["ate_rmse_m"], rel=1e-9)
    assert 0.5 * sigma < m["rpe_t_m_per_frame"] < 4.0 * sigma
    # The offset itself, from one track's poses.
    T_gt = scene.tracks[1]
    T_est = np.stack([e.T_w_o for frame in noisy for e in frame if e.track_id == 11])
    errors = track_errors(T_est, T_gt, np.arange(n))
    assert np.linalg.norm(errors["T_off"][:3, 3] - T_OFF_TRUE[:3, 3]) < 0.05  # ~sigma / sqrt(n) = 0.009 per axis
    R_err = errors["T_off"][:3, :3].T @ T_OFF_TRUE[:3, :3]
    assert np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1))) < 0.5
    assert errors["pairs"] == n - 1


def test_world_ate_includes_ego_drift_and_camera_relative_ate_does_not():
    n = 30
    scene = Scene(n, three_cars(n))
    drift = se3_exp(np.outer(np.arange(n) / n, (0.3, 0.0, 0.5, 0.0, 0.02, 0.0)))
    est, T_w_c_est = scene.estimate({g: {i: 10 + g for i in range(n)} for g in (1, 2, 3)}, drift=drift)
    m = evaluate_scene(scene, est, T_w_c_est)
    assert m["ate_cam_rmse_m"] < 1e-9
    assert m["ate_rmse_m"] > 0.05


# ---------------------------------------------------------------- matching, TP ratio, id switches


def test_id_switch_reid_after_occlusion_missing_track_and_range():
    n = 30
    tracks = three_cars(n)
    tracks[4] = gt_track(4, n, (0.0, 0.8, 45.0), 5.0)  # always beyond 30 m
    tracks[5] = gt_track(5, n, (2.0, 0.8, 12.0), 5.0)  # visible in 6 frames only
    hidden = {2: range(12, 16), 5: range(6, n)}
    scene = Scene(n, tracks, hidden)
    assignment = {
        1: {i: 10 if i < 18 else 11 for i in range(n)},  # switches while visible
        2: {i: 20 if i < 12 else 21 for i in range(n) if i not in hidden[2]},  # new id after the occlusion
        4: {i: 40 for i in range(n)},
        5: {i: 50 for i in range(6)},
    }
    est, T_w_c_est = scene.estimate(assignment)
    m = evaluate_scene(scene, est, T_w_c_est)
    assert set(m["per_track"]) == {"1", "2", "3"}  # 4 beyond range, 5 visible too briefly
    t1, t2, t3 = (m["per_track"][k] for k in ("1", "2", "3"))
    assert t1["matched_est_id"] == 10 and t1["tp_ratio"] == pytest.approx(18 / 30)
    assert t1["id_switches"] == 1 and t1["reid_switches"] == 0 and t1["max_gap_s"] == 0.0
    assert t1["id_switch_frames"] == [[18, 10, 11]] and t1["reid_switch_frames"] == []
    assert t2["visible_frames"] == 26 and t2["matched_est_id"] == 21 and t2["tp_ratio"] == pytest.approx(14 / 26)
    assert t2["id_switches"] == 0 and t2["reid_switches"] == 1 and t2["max_gap_s"] == pytest.approx(0.5)
    assert t2["id_switch_frames"] == [] and t2["reid_switch_frames"] == [[16, 20, 21]]
    assert t3["matched_est_id"] is None and t3["tp_ratio"] == 0.0 and t3["ate_m"] is None
    assert m["gt_tracks"] == 3 and m["matched_tracks"] == 2 and m["est_tracks"] == 6
    assert m["id_switches"] == 1 and m["reid_switches"] == 1
    assert m["tp_ratio"] == pytest.approx((18 / 30 + 14 / 26 + 0.0) / 3)
    assert m["ate_rmse_m"] < 1e-9  # the mean is over the matched tracks only
    # A longer range admits track 4; fewer required frames admit track 5.
    wide = evaluate_scene(scene, est, T_w_c_est, max_range_m=60.0, min_visible_frames=5)
    assert set(wide["per_track"]) == {"1", "2", "3", "4", "5"}
    assert wide["per_track"]["4"]["tp_ratio"] == 1.0 and wide["per_track"]["5"]["matched_est_id"] == 50


def test_short_gaps_count_occlusions_of_at_most_one_second_tracked_on_both_sides():
    """Issue 4: "an object that is occluded for <= 1 s keeps its track id". A gap is a run of frames where the
    GT is not eligible (hidden; with UNOCCLUDED_PROTOCOL also listed but occluded) between two eligible ones;
    its ends are the last estimate before it and the first one after it (a track reported a frame late)."""
    n = 40
    hidden = {1: [*range(10, 15), *range(30, 34)], 2: range(10, 15), 3: range(5, 20)}
    scene = Scene(n, three_cars(n), hidden)
    for i in range(25, 30):  # car 2 listed but partly occluded (KITTI level 1)
        scene.gt[i] = [dataclasses.replace(g, occlusion=1) if g.track_id == 2 else g for g in scene.gt[i]]
    assignment = {
        1: {i: 10 for i in range(n) if i not in hidden[1] and i < 34},  # 0.6 s gap kept; 0.5 s gap untracked after
        2: {i: 20 if i < 10 else 21 for i in range(n) if i not in hidden[2] and i != 15},  # 0.6 s gap, new id from f16
        3: {i: 30 if i < 5 else 31 for i in range(n) if i not in hidden[3]},  # 1.6 s gap: not a short one
    }
    est, T_w_c_est = scene.estimate(assignment)
    m = evaluate_scene(scene, est, T_w_c_est)
    rows = m["per_track"]
    assert [(rows[k]["short_gaps"], rows[k]["short_gaps_kept"]) for k in "123"] == [(1, 1), (1, 0), (0, 0)]
    assert rows["3"]["reid_switches"] == 1 and rows["3"]["max_gap_s"] == pytest.approx(1.6)
    assert (m["short_gaps"], m["short_gaps_kept"]) == (2, 1)
    u = evaluate_object_tracks(scene.gt, scene.T_w_c, scene.times, est, T_w_c_est, UNOCCLUDED_PROTOCOL)
    assert (u["per_track"]["2"]["short_gaps"], u["per_track"]["2"]["short_gaps_kept"]) == (2, 1)
    assert (u["short_gaps"], u["short_gaps_kept"]) == (3, 2) and u["id_switches"] == 0
    assert evaluate_scene(scene, est, T_w_c_est, short_gap_s=0.5)["short_gaps"] == 0


def test_paper_protocol_scores_only_unoccluded_untruncated_frames_at_least_40_px_high():
    n = 30
    scene = Scene(n, three_cars(n))
    est, T_w_c_est = scene.estimate({g: {i: 10 + g for i in range(n) if i < 20} for g in (1, 2, 3)})
    # Track 1 partly occluded in frames 0-9, track 2 truncated in frames 0-24, track 3 always < 40 px.
    for i, frame in enumerate(scene.gt):
        for k, g in enumerate(frame):
            l, t, r, b = g.box2d
            box = (l, t, r, t + (30.0 if g.track_id == 3 else max(b - t, 45.0)))
            frame[k] = dataclasses.replace(g, box2d=box, occlusion=int(g.track_id == 1 and i < 10),
                                           truncation=0.3 if g.track_id == 2 and i < 25 else 0.0)
    every = evaluate_scene(scene, est, T_w_c_est)
    assert set(every["per_track"]) == {"1", "2", "3"}
    assert every["tp_ratio"] == pytest.approx(20 / 30)
    paper = evaluate_object_tracks(scene.gt, scene.T_w_c, scene.times, est, T_w_c_est, PAPER_PROTOCOL)
    # Track 1 is scored over frames 10-29 (tracked in 10-19), track 2 has 5 frames (< 10): not scored.
    assert set(paper["per_track"]) == {"1"}
    assert paper["per_track"]["1"]["visible_frames"] == 20
    assert paper["per_track"]["1"]["tp_ratio"] == pytest.approx(10 / 20)


def test_box_iou_matching_without_instance_ids():
    n = 20
    scene = Scene(n, three_cars(n))
    est, T_w_c_est = scene.estimate({1: {i: 7 for i in range(n)}, 2: {i: 8 for i in range(n)}}, with_instances=False)
    for i in range(10, n):  # track 8 drifts off its GT box in the second half
        e = est[i][1]
        left, top, right, bottom = e.box2d
        e.box2d = (left + 0.9 * (right - left), top, right + 0.9 * (right - left), bottom)
    m = evaluate_scene(scene, est, T_w_c_est)
    assert m["per_track"]["1"]["matched_est_id"] == 7 and m["per_track"]["1"]["tp_ratio"] == 1.0
    assert m["per_track"]["2"]["matched_est_id"] == 8 and m["per_track"]["2"]["tp_ratio"] == pytest.approx(0.5)
    assert m["per_track"]["3"]["matched_est_id"] is None
    # With instance ids present, a wrong id means no overlap whatever the boxes.
    for frame in est:
        for e in frame:
            e.instance_id = mots_id(99)
    assert evaluate_scene(scene, est, T_w_c_est)["matched_tracks"] == 0
    assert evaluate_scene(scene, est, T_w_c_est, use_instance_ids=False)["matched_tracks"] == 2


def test_box_iou_values():
    a = np.array([[0.0, 0.0, 10.0, 10.0]])
    b = np.array([[5.0, 0.0, 15.0, 10.0], [20.0, 20.0, 30.0, 30.0], [np.nan] * 4, [0.0, 0.0, 10.0, 10.0]])
    assert np.allclose(box_iou(a, b), [[50.0 / 150.0, 0.0, 0.0, 1.0]])
    inner = np.array([[2.0, 2.0, 4.0, 4.0], [8.0, 0.0, 12.0, 10.0], [3.0, 3.0, 3.0, 3.0]])
    assert np.allclose(box_covered(a, np.r_[b, inner]), [[0.5, 0.0, 0.0, 1.0, 1.0, 0.5, 0.0]])


def test_velocity_to_world_matches_the_constant_velocity_model():
    T_w_o = make_pose(so3_exp(np.array([0.2, -0.7, 0.3])), np.array([1.0, 2.0, 3.0]))
    v_o, w_o, dt = np.array([5.0, 0.2, -0.1]), np.array([0.0, 0.3, 0.05]), 1e-6
    T_next = T_w_o @ make_pose(so3_exp(w_o * dt), v_o * dt)  # paper eq. 5
    v_w, w_w = velocity_to_world(T_w_o, v_o, w_o)
    assert np.allclose((T_next[:3, 3] - T_w_o[:3, 3]) / dt, v_w)
    dR = T_next[:3, :3] @ T_w_o[:3, :3].T
    assert np.allclose(np.array([dR[2, 1], dR[0, 2], dR[1, 0]]) / dt, w_w, atol=1e-5)


# ---------------------------------------------------------------- results files


def frame_status():
    return {"state": "ok", "n_static_matches": 100, "n_dynamic_matches": 10, "keyframe": False}


def sample_objects(i: int, T_w_c: np.ndarray) -> list[ObjectEstimate]:
    """A car without a 3D box and a van with one (box frame: heading along the camera's +z)."""
    car = ObjectEstimate(3, "car", T_w_c @ make_pose(np.eye(3), np.array([1.0, 0.5, 9.0 + i])),
                         np.array([0.0, 0.0, 6.0]), np.array([0.0, 0.1, 0.0]), n_points=25 + i, instance_id=1003,
                         box2d=(10.0, 12.0, 30.0, 33.5))
    T_o_b = make_pose(R_HEADING_Z, np.array([0.2, 0.3, 1.1]))
    van = ObjectEstimate(8, "van", T_w_c @ make_pose(so3_exp(np.array([0.0, 0.2, 0.0])), np.array([-3.0, 0.4, 15.0])),
                         np.zeros(3), np.zeros(3), n_points=60, instance_id=0, box2d=None, T_o_b=T_o_b,
                         dims=(5.0, 2.0, 2.2))
    return [car, van] if i != 2 else []


def test_objects_round_trip_and_tracks_txt(tmp_path):
    T_w_c = camera_poses(4)
    res = tmp_path / "res"
    written = []
    with ResultsWriter(res) as writer:
        for i in range(4):
            writer.write_frame(i, T_w_c[i], frame_status(), {"total": 5.0})
            objects = sample_objects(i, T_w_c[i])
            writer.write_objects(i, T_w_c[i], objects)
            written.append(objects)
    results = read_results(res)
    assert results.has_objects and [len(f) for f in results.objects] == [2, 2, 0, 2]
    for got_frame, want_frame in zip(results.objects, written):
        for got, want in zip(got_frame, want_frame):
            assert (got.track_id, got.cls, got.n_points, got.instance_id) == (want.track_id, want.cls, want.n_points,
                                                                                want.instance_id)
            assert np.array_equal(got.T_w_o, want.T_w_o) and np.array_equal(got.v_w, want.v_w)
            assert got.box2d == want.box2d and got.dims == want.dims
            assert (got.T_o_b is None) == (want.T_o_b is None)
    assert np.array_equal(results.objects[0][1].T_o_b, written[0][1].T_o_b)
    assert (res / "objects.jsonl").read_text().splitlines()[2] == '{"frame": 2, "objects": []}'

    labels = read_tracking_labels(res / "tracks.txt")
    assert [(lb.frame, lb.track_id, lb.type) for lb in labels] == [
        (f, t, k) for f in (0, 1, 3) for t, k in ((3, "Car"), (8, "Van"))]
    for lb in labels:
        car, van = sample_objects(lb.frame, T_w_c[lb.frame])
        if lb.track_id == 3:  # no box: the object-frame origin in the camera, no size, orientation unknown
            assert np.allclose(lb.location, (1.0, 0.5, 9.0 + lb.frame), atol=1e-6)
            assert lb.dims_hwl == (0.0, 0.0, 0.0) and lb.rotation_y == -10.0 and lb.alpha == -10.0
            assert lb.box2d == (10.0, 12.0, 30.0, 33.5) and lb.score == 25 + lb.frame
        else:  # a box: KITTI's bottom-face centre and heading, read back to the same box
            T_w_b, dims = label_to_object_pose(lb, T_w_c[lb.frame])
            assert np.allclose(T_w_b, van.T_w_b(), atol=1e-5) and dims == pytest.approx(van.dims)
            assert lb.box2d == (-1.0, -1.0, -1.0, -1.0) and lb.score == 60.0


def test_runs_without_objects_read_as_empty_frames_and_a_crash_keeps_complete_frames(tmp_path):
    T_w_c = camera_poses(3)
    with ResultsWriter(tmp_path / "static") as writer:
        for i in range(3):
            writer.write_frame(i, T_w_c[i], frame_status(), {})
    results = read_results(tmp_path / "static")
    assert not results.has_objects and results.objects == [[], [], []]
    assert not (tmp_path / "static" / "objects.jsonl").exists()

    res = tmp_path / "dynamic"
    writer = ResultsWriter(res)
    for i in range(3):
        writer.write_frame(i, T_w_c[i], frame_status(), {})
        writer.write_objects(i, T_w_c[i], sample_objects(i, T_w_c[i]))
    writer.write_frame(3, T_w_c[0], frame_status(), {})  # "crash" before frame 3's objects
    assert len(read_results(res)) == 3
    with open(res / "objects.jsonl", "a") as f:
        f.write('{"frame": 3, "obj')  # cut mid-line
    assert len(read_results(res)) == 3
    writer.close()


def test_object_writer_and_reader_reject_bad_input(tmp_path):
    T = np.eye(4)
    car = sample_objects(0, T)[0]
    with ResultsWriter(tmp_path / "res") as writer:
        with pytest.raises(ValueError, match="expected frame 0"):
            writer.write_objects(1, T, [])
        with pytest.raises(ValueError, match="duplicate track ids"):
            writer.write_objects(0, T, [car, car])
        with pytest.raises(ValueError, match="together"):
            writer.write_objects(0, T, [ObjectEstimate(1, "car", T, np.zeros(3), np.zeros(3), 5, T_o_b=np.eye(4))])
        with pytest.raises(ValueError, match="class"):
            writer.write_objects(0, T, [ObjectEstimate(1, "tram", T, np.zeros(3), np.zeros(3), 5)])
        with pytest.raises(ValueError, match="T_w_o"):
            writer.write_objects(0, T, [ObjectEstimate(1, "car", np.full((4, 4), np.nan), np.zeros(3), np.zeros(3), 5)])
        assert not (tmp_path / "res" / "objects.jsonl").exists()  # nothing written by the refused calls
        writer.write_frame(0, T, frame_status(), {})
        writer.write_objects(0, T, [car])
    path = tmp_path / "res" / "objects.jsonl"
    record = json.loads(path.read_text())
    del record["objects"][0]["n_points"]
    path.write_text(json.dumps(record) + "\n")
    with pytest.raises(InputError, match=r"objects.jsonl line 1: invalid object record"):
        read_results(tmp_path / "res")
    path.write_text('{"frame": 1, "objects": []}\n')
    with pytest.raises(InputError, match=r"objects.jsonl line 1: expected"):
        read_results(tmp_path / "res")


# ---------------------------------------------------------------- dynaslam2 eval end to end


def write_sequence(path, scene: Scene) -> None:
    blank = np.zeros((H, W, 3), np.uint8)
    with SequenceWriter(path, CAMERA, {"fps": FPS}, with_depth=False) as writer:
        for i in range(scene.n):
            frame = FrameData(i, float(scene.times[i]), blank, blank, None, np.zeros((H, W), np.uint16))
            writer.write_frame(frame, scene.T_w_c[i], scene.gt[i])


def write_run(path, scene: Scene, est, T_w_c_est) -> None:
    with ResultsWriter(path) as writer:
        for i in range(scene.n):
            writer.write_frame(i, T_w_c_est[i], frame_status(), {"total": 20.0})
            if est is not None:
                writer.write_objects(i, T_w_c_est[i], est[i])


def test_cli_eval_scores_objects_end_to_end(tmp_path, capsys):
    n = 20
    scene = Scene(n, three_cars(n), hidden={3: range(5, 8)})
    est, T_w_c_est = scene.estimate({1: {i: 4 for i in range(n)}, 2: {i: 5 if i < 15 else 6 for i in range(n)}},
                                    np.random.default_rng(1), noise_m=0.03)
    write_sequence(tmp_path / "seq", scene)
    write_run(tmp_path / "res", scene, est, T_w_c_est)
    assert main(["eval", str(tmp_path / "seq"), str(tmp_path / "res")]) == 0
    out = capsys.readouterr().out
    m = json.loads((tmp_path / "res" / "metrics.json").read_text())
    # The files (%.9e poses, JSON floats) give the same figures as the in-memory estimates.
    direct = evaluate_scene(scene, est, T_w_c_est)
    assert m["objects"]["ate_rmse_m"] == pytest.approx(direct["ate_rmse_m"], abs=1e-6)
    assert m["objects"]["per_track"]["2"]["id_switches"] == 1
    assert m["objects"]["per_track"]["2"]["id_switch_frames"] == [[15, 5, 6]]
    assert m["objects"]["per_track"]["2"]["tp_ratio"] == pytest.approx(15 / 20)
    assert m["objects"]["per_track"]["3"]["matched_est_id"] is None
    assert m["objects"]["gt_tracks"] == 3 and m["objects"]["matched_tracks"] == 2
    assert 0.01 < m["objects"]["ate_rmse_m"] < 0.1
    seq = open_sequence(tmp_path / "seq")
    results = read_results(tmp_path / "res")
    assert json.loads(json.dumps(evaluate_objects(seq, results.objects, results.T_w_c))) == m["objects"]
    for key in ("objects.ate_rmse_m", "objects.rpe_t_m_per_frame", "objects.per_track.1.tp_ratio",
                "objects.per_track.2.matched_est_id", "objects.id_switches", "ego.ate_rmse_m"):
        assert key in out
    assert format_table(m) in out
    assert re.search(r"objects\.per_track\.2\.id_switch_frames +\[\[15, 5, 6\]\]", out)
    # A run without objects (static/masked) has no objects section.
    write_run(tmp_path / "static", scene, None, T_w_c_est)
    assert "objects" not in evaluate(tmp_path / "seq", tmp_path / "static")
