"""End-to-end tests of the SLAM system and `dynaslam2 run`: real KITTI accuracy, loss and recovery,
determinism, masked vs static on a simulated dynamic scene, and bad input."""

from __future__ import annotations

import dataclasses
import json
import shutil
import types
from pathlib import Path

import numpy as np
import pytest

from dynaslam2.cli import main
from dynaslam2.config import load_config
from dynaslam2.config_tree import to_dict
from dynaslam2.eval.report import evaluate
from dynaslam2.io.results import read_results
from dynaslam2.io.sequence import open_sequence
from dynaslam2.map.objects import ObjectObservation
from dynaslam2.optim.synthetic import kitti_like_camera
from dynaslam2.runner import run_sequence
from dynaslam2.system import System

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
KITTI06 = DATA / "kitti-odometry-06"
needs_kitti = pytest.mark.skipif(not KITTI06.is_dir(), reason=f"real KITTI odometry clip not found at {KITTI06}")


@pytest.fixture(scope="module")
def kitti_static_run(tmp_path_factory) -> Path:
    res = tmp_path_factory.mktemp("kitti06") / "res"
    assert main(["run", str(KITTI06), "--mode", "static", "--out", str(res), "--quiet"]) == 0
    return res


@needs_kitti
@pytest.mark.slow
def test_kitti06_static_accuracy(kitti_static_run):
    """Issue 3's proof on the real KITTI odometry 06 clip (51 frames, ~60 m)."""
    metrics = evaluate(KITTI06, kitti_static_run)
    ego = metrics["ego"]
    assert ego["frames"] == 51 and ego["lost_frames"] == 0
    assert ego["ate_rmse_m"] <= 0.3
    assert ego["rpe_t_m_per_frame"] <= 0.03
    results = read_results(kitti_static_run)
    assert results.status[0]["state"] == "init"
    assert all(s["state"] == "ok" for s in results.status[1:])
    assert sum(s["keyframe"] for s in results.status) >= 5
    assert np.all(results.timing["total"] > 0)


def _frames(seq, indices, black=()):
    for i in indices:
        data = seq[i]
        if i in black:
            data = dataclasses.replace(data, left=np.zeros_like(data.left), right=np.zeros_like(data.right))
        yield data


@needs_kitti
def test_black_stretch_is_flagged_lost_then_relocalized():
    seq = open_sequence(KITTI06)
    system = System(load_config(None, ["mode=static"]), seq.camera)
    black = set(range(10, 15))
    estimates = [system.process(d) for d in _frames(seq, range(22), black)]
    states = [e.state for e in estimates]
    assert states[:10] == ["init"] + ["ok"] * 9
    assert states[10:15] == ["lost"] * 5
    assert states[15] == "relocalized" and all(s == "ok" for s in states[16:])
    # Lost frames carry the constant-velocity prediction; relocalization lands back on the track.
    gt = seq.gt_T_w_c
    err = [np.linalg.norm(e.T_w_c[:3, 3] - gt[e.index][:3, 3]) for e in estimates]
    assert max(err[10:15]) < 0.5 and max(err[15:]) < 0.3


@needs_kitti
def test_frames_before_the_map_begins_are_lost_at_identity():
    """A sequence whose first frames cannot begin a map (black: no features) reports them lost at the identity
    pose, the world frame, and begins the map on the first frame that can (no exception)."""
    seq = open_sequence(KITTI06)
    system = System(load_config(None, ["mode=static"]), seq.camera)
    estimates = [system.process(d) for d in _frames(seq, range(8), black={0, 1, 2})]
    assert [e.state for e in estimates] == ["lost"] * 3 + ["init"] + ["ok"] * 4
    assert all(np.array_equal(e.T_w_c, np.eye(4)) for e in estimates[:4])
    # Frames 4-7 relative to the map's first frame, as the ground truth has them.
    gt_rel = [np.linalg.inv(seq.gt_T_w_c[3]) @ seq.gt_T_w_c[e.index] for e in estimates[4:]]
    assert max(np.linalg.norm(e.T_w_c[:3, 3] - g[:3, 3]) for e, g in zip(estimates[4:], gt_rel)) < 0.1


@needs_kitti
def test_jump_starts_a_new_segment_from_the_motion_prior():
    """Frames 0-11 then 35-45: relocalization against the old map fails, so after the configured
    number of lost frames a new map segment starts (no exception, poses stay finite)."""
    seq = open_sequence(KITTI06)
    system = System(load_config(None, ["mode=static", "tracking.lost_frames_before_new_segment=2"]), seq.camera)
    estimates = [system.process(d) for d in _frames(seq, list(range(12)) + list(range(35, 46)))]
    states = [e.state for e in estimates]
    assert states[12] == "lost"
    assert "new_segment" in states[12:]
    k = states.index("new_segment")
    assert all(s == "lost" for s in states[12:k]) and k - 12 == 2  # 2 lost frames, then a new map
    assert estimates[k].segment == 1 and all(s == "ok" for s in states[k + 1:])
    assert all(np.all(np.isfinite(e.T_w_c)) for e in estimates)


@needs_kitti
def test_two_runs_give_identical_poses():
    seq = open_sequence(KITTI06)
    runs = []
    for _ in range(2):
        system = System(load_config(None, ["mode=static"]), seq.camera)
        runs.append(np.array([system.process(seq[i]).T_w_c for i in range(12)]))
    assert np.array_equal(runs[0], runs[1])


@pytest.mark.slow
def test_static_scene_accuracy(tmp_path):
    """Issue 3's proof on the simulated `static` scenario (640x480, 100 frames, seed 0, ~85 m):
    ATE RMSE <= 0.05 m, no lost frame."""
    pytest.importorskip("mujoco")
    from sim.generate import generate_sequence
    from sim.scenarios import load_scenario

    seq = generate_sequence(load_scenario("static", ["frames=100", "seed=0"]), tmp_path / "seq", progress=False)
    ego = evaluate(seq, run_sequence(seq, "static", tmp_path / "res", progress=False))["ego"]
    print(f"static scenario, 100 frames 640x480: ATE {ego['ate_rmse_m']:.4f} m, RPE_t {ego['rpe_t_m_per_frame']:.4f} m")
    assert ego["lost_frames"] == 0
    assert ego["ate_rmse_m"] <= 0.05


@pytest.mark.slow
def test_masked_beats_static_on_a_dynamic_scene(tmp_path):
    """Simulated 'following' scene (a vehicle ahead moving with the ego), 150 frames as the issue's claims:
    masked < static ATE. (On 50 frames the two tie within 2 % on world 2: the lead car's pull builds up.)"""
    pytest.importorskip("mujoco")
    from sim.generate import generate_sequence
    from sim.scenarios import load_scenario

    cfg = load_scenario("following", ["frames=150", "seed=0"])
    seq = generate_sequence(cfg, tmp_path / "seq", progress=False)
    ate = {}
    for mode in ("static", "masked"):
        res = run_sequence(seq, mode, tmp_path / mode, progress=False)
        ate[mode] = evaluate(seq, res)["ego"]["ate_rmse_m"]
    print(f"following, 150 frames 640x480: ATE static {ate['static']:.4f} m, masked {ate['masked']:.4f} m")
    assert ate["masked"] < ate["static"]


def _tiny_kitti(root: Path, right_width: int = 64, calib_value: str = "100.0") -> Path:
    import cv2

    rng = np.random.default_rng(0)
    for name, width in (("image_0", 64), ("image_1", right_width)):
        (root / name).mkdir(parents=True)
        for i in range(3):
            cv2.imwrite(str(root / name / f"{i:06d}.png"), rng.integers(0, 256, (48, width)).astype(np.uint8))
    p0 = f"P0: {calib_value} 0 32 0 0 100 24 0 0 0 1 0"
    p1 = "P1: 100 0 32 -50 0 100 24 0 0 0 1 0"
    (root / "calib.txt").write_text(p0 + "\n" + p1 + "\n")
    (root / "times.txt").write_text("0.0\n0.1\n0.2\n")
    return root


@pytest.mark.parametrize("case, words", [("missing", "seq"), ("sizes", "right image"), ("nan_calib", "calib"),
                                         ("bad_set", "no_such_key"), ("masked", "instance masks"),
                                         ("dynamic", "instance masks"), ("depth_image", "use_depth_image")])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, case, words):
    """Including a mode or setting the sequence cannot serve (KITTI odometry has no instance masks and no depth
    images): one error line naming what is missing, and no results folder."""
    seq = tmp_path / "seq"
    mode, args = "static", []
    if case == "sizes":
        _tiny_kitti(seq, right_width=80)
    elif case == "nan_calib":
        _tiny_kitti(seq, calib_value="nan")
    elif case != "missing":
        _tiny_kitti(seq)
    if case == "bad_set":
        args = ["--set", "tracking.no_such_key=1"]
    elif case in ("masked", "dynamic"):
        mode = case
    elif case == "depth_image":
        args = ["--set", "tracking.use_depth_image=true"]
    code = main(["run", str(seq), "--mode", mode, "--out", str(tmp_path / "res"), "--quiet", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("dynaslam2 run: error:") and words in err[0], err
    assert not (tmp_path / "res").exists()


def test_run_records_what_made_the_results_and_eval_refuses_another_sequences(tmp_path, capsys):
    """RES/run.json holds the mode, the whole config and the sequence's fingerprint (equal for a copy of the
    sequence, not for one with other timestamps); eval of those results against another sequence of the same
    length is one error line naming both, instead of scores against the wrong ground truth."""
    seq_a, seq_b = _tiny_kitti(tmp_path / "a"), _tiny_kitti(tmp_path / "b")
    (seq_b / "times.txt").write_text("0.0\n0.05\n0.1\n")
    for seq in (seq_a, seq_b):
        (seq / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    shutil.copytree(seq_a, tmp_path / "a_copy")
    res = tmp_path / "res"
    assert main(["run", str(seq_a), "--mode", "static", "--out", str(res), "--quiet",
                 "--set", "orb.n_features=500"]) == 0
    run = json.loads((res / "run.json").read_text())
    assert run["mode"] == "static" and run["sequence"] == str(seq_a.resolve())
    assert run["config"] == to_dict(load_config(None, ["orb.n_features=500", "mode=static"]))
    fingerprint = open_sequence(seq_a).fingerprint()
    assert run["sequence_fingerprint"] == fingerprint == open_sequence(tmp_path / "a_copy").fingerprint()
    assert open_sequence(seq_b).fingerprint() != fingerprint
    assert main(["eval", str(tmp_path / "a_copy"), str(res), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["eval", str(seq_b), str(res), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds results of" in err[0] and str(seq_b) in err[0], err
    (res / "run.json").unlink()  # results written before run.json existed are scored as before
    assert main(["eval", str(seq_b), str(res), "--quiet"]) == 0


@needs_kitti
def test_a_crash_mid_sequence_keeps_the_frames_written(tmp_path, capsys):
    """A frame that cannot be read stops the run with one error line; earlier frames stay readable."""
    seq = tmp_path / "seq"
    for name in ("image_0", "image_1"):
        (seq / name).mkdir(parents=True)
        for i in range(4):
            shutil.copy(KITTI06 / name / f"{i:06d}.png", seq / name / f"{i:06d}.png")
    shutil.copy(KITTI06 / "calib.txt", seq / "calib.txt")
    (seq / "times.txt").write_text("".join(f"{0.1 * i}\n" for i in range(4)))
    (seq / "image_0" / "000003.png").write_bytes(b"not a png")
    code = main(["run", str(seq), "--mode", "static", "--out", str(tmp_path / "res"), "--quiet"])
    assert code == 2 and len(capsys.readouterr().err.strip().splitlines()) == 1
    results = read_results(tmp_path / "res")
    assert len(results) == 3 and results.status[0]["state"] == "init"


@pytest.mark.parametrize("override, expected", [([], [True, False]),
                                                (["objects.object_keyframe_triangulates=true"], [True, True])])
def test_keyframe_for_an_object_only_triangulates_no_static_points(override, expected):
    """III-D: a keyframe inserted because an object is weak (the camera is not) adds no new static points
    from matches with its neighbours, unless objects.object_keyframe_triangulates."""
    system = System(load_config(None, ["mode=dynamic", "objects.ba=false"] + override), kitti_like_camera())
    calls = []
    system.mapper.process = lambda kf, map_, static_ba=True, triangulate=True: calls.append(triangulate) or {}
    system.object_tracker.on_keyframe = lambda *args: None
    for camera_weak in (True, False):
        system._local_mapping(None, types.SimpleNamespace(id=0), camera_weak, [1])
    assert calls == expected



@pytest.mark.parametrize("all_objects, expected", [(False, [0]), (True, [0, 1])])
def test_ba_with_objects_takes_the_weak_objects_or_every_object_of_the_keyframe(monkeypatch, all_objects, expected):
    """III-D: a keyframe's BA with objects optimizes its weak objects; with objects.ba_all_objects every object
    observed at the keyframe with points joins them (not one seen at another frame, nor one without points). A
    keyframe without a weak object runs none either way."""
    system = System(load_config(None, ["mode=dynamic", f"objects.ba_all_objects={all_objects}"]), kitti_like_camera())
    system.mapper.process = lambda *args, **kwargs: {}
    system.object_tracker.on_keyframe = lambda *args: None
    calls = []
    monkeypatch.setattr("dynaslam2.system.object_local_ba", lambda kf, map_, objects, weak, *args: calls.append(weak))
    for pt_ids, kf_id, frame_index in (([5, 6], 7, 3), ([8], 7, 3), ([9], 2, 1), ([], 7, 3)):
        track = system.objects.new_track("car")
        track.observations.append(ObjectObservation(
            frame_index, 0.1 * frame_index, np.eye(4), np.zeros(3), np.zeros(3), 1001, np.arange(len(pt_ids)),
            np.array(pt_ids, dtype=np.int64), kf_id=kf_id))
    for weak in ([0], []):
        system._local_mapping(types.SimpleNamespace(index=3), types.SimpleNamespace(id=7), False, weak)
    assert calls == [expected]


def test_camera_keyframe_decision_ignores_object_only_keyframes():
    """III-D reason (a) is ORB-SLAM2's decision on the static map: its reference is the tracking reference
    keyframe unless that one was inserted only for an object; then the newest camera keyframe (while it is in
    the map). In `masked` and `static` modes every keyframe is a camera keyframe: ORB-SLAM2's reference."""
    system = System(load_config(None, ["mode=dynamic"]), kitti_like_camera())
    camera_kf, object_kf = types.SimpleNamespace(object_only=False), types.SimpleNamespace(object_only=True)
    system.map.keyframes.update({3: camera_kf, 4: object_kf})
    system.camera_kf_id = 3
    system.ref_kf_id = 4
    assert system._camera_reference() is camera_kf
    system.ref_kf_id = 3
    assert system._camera_reference() is camera_kf
    del system.map.keyframes[3]  # culled: the reference keyframe itself
    system.ref_kf_id = 4
    assert system._camera_reference() is object_kf
