"""Trajectory metrics (cross-checked against evo), the results files, and `dynaslam2 eval`."""

import copy
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.core.geometry import GeometryException
from evo.core.metrics import PoseRelation, StatisticsType, Unit
from evo.core.trajectory import PosePath3D

from dynaslam2.cli import main
from dynaslam2.errors import InputError
from dynaslam2.eval.report import evaluate, format_table
from dynaslam2.eval.trajectory import ate, rpe, umeyama_alignment
from dynaslam2.geometry.se3 import se3_exp
from dynaslam2.io.kitti import read_poses
from dynaslam2.io.results import STAGES, ResultsWriter, read_results

KITTI_06 = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti-odometry-06"
TOL = 1e-6


def drive(n, rng):
    """A smooth ground-truth drive: forward with lateral sway, yaw and some pitch/roll."""
    s = np.linspace(0.0, 1.0, n)
    xi = np.zeros((n, 6))
    xi[:, 0] = 3.0 * np.sin(4 * s) + rng.normal(0, 0.01, n)
    xi[:, 1] = 0.5 * np.cos(3 * s)
    xi[:, 2] = 40.0 * s
    xi[:, 3:] = np.stack([0.1 * np.sin(5 * s), 1.2 * s, 0.05 * np.cos(2 * s)], -1)
    return se3_exp(xi)


def perturbed(T_gt, rng, t_sigma, r_sigma):
    """An estimate: GT in another world frame, with per-frame noise (random walk plus jitter)."""
    n = len(T_gt)
    offset = se3_exp(np.concatenate([rng.normal(0, 2.0, 3), rng.normal(0, 0.5, 3)]))
    walk = np.cumsum(np.concatenate([rng.normal(0, t_sigma, (n, 3)), rng.normal(0, r_sigma, (n, 3))], -1), 0)
    jitter = np.concatenate([rng.normal(0, t_sigma, (n, 3)), rng.normal(0, r_sigma, (n, 3))], -1)
    return offset @ T_gt @ se3_exp(walk) @ se3_exp(jitter)


def evo_reference(T_est, T_gt, align=True, delta=1):
    """evo's APE (translation, after SE(3) Umeyama if align) and RPE (translation, rotation in degrees)."""
    ref, est = PosePath3D(poses_se3=list(T_gt)), PosePath3D(poses_se3=list(T_est))
    aligned = copy.deepcopy(est)
    if align:
        aligned.align(ref, correct_scale=False)
    ape = evo_metrics.APE(PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    rpes = {}
    for name, relation in (("t", PoseRelation.translation_part), ("r", PoseRelation.rotation_angle_deg)):
        metric = evo_metrics.RPE(relation, delta=delta, delta_unit=Unit.frames, all_pairs=False)
        metric.process_data((ref, est))
        rpes[name] = metric
    return ape, rpes


def assert_matches_evo(T_est, T_gt, align=True, delta=1):
    """Every statistic and every per-frame error equals evo's within TOL; returns the largest difference."""
    ape, rpes = evo_reference(T_est, T_gt, align, delta)
    ours_ate = ate(T_est, T_gt, align="se3" if align else "none")
    ours_rpe = rpe(T_est, T_gt, delta=delta)
    pairs = [
        (ours_ate["rmse_m"], ape.get_statistic(StatisticsType.rmse)),
        (ours_ate["mean_m"], ape.get_statistic(StatisticsType.mean)),
        (ours_ate["median_m"], ape.get_statistic(StatisticsType.median)),
        (ours_ate["max_m"], ape.get_statistic(StatisticsType.max)),
        (ours_rpe["t_rmse_m"], rpes["t"].get_statistic(StatisticsType.rmse)),
        (ours_rpe["t_mean_m"], rpes["t"].get_statistic(StatisticsType.mean)),
        (ours_rpe["r_rmse_deg"], rpes["r"].get_statistic(StatisticsType.rmse)),
        (ours_rpe["r_mean_deg"], rpes["r"].get_statistic(StatisticsType.mean)),
    ]
    diffs = [abs(ours - ref) for ours, ref in pairs]
    diffs.append(np.max(np.abs(ours_ate["errors_m"] - ape.error)))
    assert ours_rpe["t_errors_m"].shape == rpes["t"].error.shape
    diffs.append(np.max(np.abs(ours_rpe["t_errors_m"] - rpes["t"].error)))
    diffs.append(np.max(np.abs(ours_rpe["r_errors_deg"] - rpes["r"].error)))
    assert max(diffs) < TOL, diffs
    assert ours_ate["rmse_m"] > 1e-3 and ours_rpe["r_rmse_deg"] > 1e-3  # the check compares non-trivial errors
    return max(diffs)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ate_and_rpe_match_evo_on_random_noisy_trajectories(seed):
    rng = np.random.default_rng(seed)
    T_gt = drive(150, rng)
    T_est = perturbed(T_gt, rng, t_sigma=0.02, r_sigma=0.004)
    assert_matches_evo(T_est, T_gt)


def test_unaligned_ate_and_rpe_with_delta_match_evo():
    rng = np.random.default_rng(5)
    T_gt = drive(120, rng)
    T_est = T_gt @ se3_exp(np.cumsum(rng.normal(0, 0.01, (120, 6)), 0))
    assert_matches_evo(T_est, T_gt, align=False, delta=1)
    assert_matches_evo(T_est, T_gt, align=True, delta=7)
    assert rpe(T_est, T_gt, delta=7)["pairs"] == len(range(0, 120, 7)) - 1


def test_ate_and_rpe_match_evo_on_real_kitti_06_ground_truth():
    if not (KITTI_06 / "poses.txt").is_file():
        pytest.skip(f"real KITTI odometry 06 clip not found at {KITTI_06}")
    T_gt = read_poses(KITTI_06 / "poses.txt")
    assert T_gt.shape == (51, 4, 4)
    rng = np.random.default_rng(6)
    T_est = perturbed(T_gt, rng, t_sigma=0.01, r_sigma=0.002)
    assert_matches_evo(T_est, T_gt)


def test_umeyama_recovers_a_known_transform_and_scale():
    rng = np.random.default_rng(7)
    X = rng.normal(size=(30, 3)) * 5
    T = se3_exp(np.array([1.0, -2.0, 3.0, 0.4, -0.3, 2.5]))
    Y = 1.7 * X @ T[:3, :3].T + T[:3, 3]
    R, t, s = umeyama_alignment(X, Y, with_scale=True)
    assert np.allclose(R, T[:3, :3], atol=1e-12) and np.allclose(t, T[:3, 3], atol=1e-10) and abs(s - 1.7) < 1e-12
    R, t, s = umeyama_alignment(X, X @ T[:3, :3].T + T[:3, 3])
    assert s == 1.0 and np.allclose(R, T[:3, :3], atol=1e-12) and np.allclose(t, T[:3, 3], atol=1e-10)


def test_rigidly_moved_trajectory_has_zero_ate_and_rpe_and_a_straight_line_is_scored():
    rng = np.random.default_rng(8)
    T_gt = drive(60, rng)
    T_est = se3_exp(np.array([5.0, 1.0, -2.0, 0.3, 1.0, -0.2])) @ T_gt
    assert ate(T_est, T_gt)["rmse_m"] < 1e-12
    assert ate(T_est, T_gt, align="none")["rmse_m"] > 1.0
    assert rpe(T_est, T_gt)["t_rmse_m"] < 1e-12 and rpe(T_est, T_gt)["r_rmse_deg"] < 1e-6
    # A straight constant-velocity drive: evo's Umeyama refuses the rank-1 covariance; ours aligns it.
    line = np.tile(np.eye(4), (40, 1, 1))
    line[:, 2, 3] = np.arange(40) * 1.0
    moved = se3_exp(np.array([2.0, 0.0, 1.0, 0.0, 0.7, 0.0])) @ line
    with pytest.raises(GeometryException):
        PosePath3D(poses_se3=list(moved)).align(PosePath3D(poses_se3=list(line)))
    assert ate(moved, line)["rmse_m"] < 1e-12
    with pytest.raises(ValueError):
        ate(T_est[:-1], T_gt)


# ---------------------------------------------------------------- results files


def status(state="ok", n_static=120, keyframe=False, **extra):
    return {"state": state, "n_static_matches": n_static, "n_dynamic_matches": 0, "keyframe": keyframe, **extra}


def write_run(res, T_w_c, states=None, total_ms=50.0):
    states = states or ["ok"] * len(T_w_c)
    with ResultsWriter(res) as writer:
        for i, (T, state) in enumerate(zip(T_w_c, states)):
            writer.write_frame(i, T, status(state, n_static=100 + i, keyframe=i % 3 == 0),
                               {"features": 10.0 + i, "tracking": 5.0, "total": total_ms + i})


def test_results_round_trip(tmp_path):
    rng = np.random.default_rng(9)
    T_w_c = drive(12, rng)
    res = tmp_path / "res"
    with ResultsWriter(res) as writer:
        for i, T in enumerate(T_w_c):
            writer.write_frame(i, T, status("lost" if i == 4 else "ok", n_static=np.int64(i), score=np.float32(0.5)),
                               {"features": 1.5 * i, "stereo": 2.0})
    assert (res / "timing.csv").read_text().splitlines()[0] == "frame," + ",".join(STAGES)
    results = read_results(res)
    assert len(results) == 12
    assert np.allclose(results.T_w_c, T_w_c, atol=1e-6)
    assert results.status[4] == {"frame": 4, "state": "lost", "n_static_matches": 4, "n_dynamic_matches": 0,
                                 "keyframe": False, "score": 0.5}
    assert set(results.timing) == set(STAGES)
    assert np.allclose(results.timing["features"], 1.5 * np.arange(12))
    assert np.all(results.timing["objects"] == 0.0)
    assert np.allclose(results.timing["total"], 1.5 * np.arange(12) + 2.0)  # missing total = sum of stages


def test_writer_rejects_bad_frames(tmp_path):
    with ResultsWriter(tmp_path / "res") as writer:
        with pytest.raises(ValueError):
            writer.write_frame(1, np.eye(4), status(), {})
        with pytest.raises(ValueError):
            writer.write_frame(0, np.eye(4), status("confused"), {})
        with pytest.raises(ValueError):
            writer.write_frame(0, np.eye(4), status(), {"tracknig": 3.0})
        with pytest.raises(ValueError):
            writer.write_frame(0, np.full((4, 4), np.nan), status(), {})
        writer.write_frame(0, np.eye(4), status(), {})
    assert len(read_results(tmp_path / "res")) == 1


def test_results_folder_checks(tmp_path):
    res = tmp_path / "res"
    write_run(res, np.tile(np.eye(4), (3, 1, 1)))
    (res / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="not empty"):
        ResultsWriter(res)
    ResultsWriter(res, overwrite=True).close()
    assert (res / "notes.txt").read_text() == "mine" and len(read_results(res)) == 0
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        ResultsWriter(tmp_path / "file")
    with pytest.raises(InputError, match="cannot create"):
        ResultsWriter(tmp_path / "file" / "res")


CRASHING_RUN = """
import os, sys
import numpy as np
from dynaslam2.io.results import ResultsWriter
writer = ResultsWriter(sys.argv[1])
for i in range(5):
    T = np.eye(4); T[2, 3] = i
    writer.write_frame(i, T, {"state": "ok", "n_static_matches": 1, "n_dynamic_matches": 0, "keyframe": False},
                       {"total": 1.0})
os._exit(3)  # killed: no close, no flush at exit
"""


def test_a_crash_keeps_the_complete_frames(tmp_path):
    res = tmp_path / "res"
    proc = subprocess.run([sys.executable, "-c", CRASHING_RUN, str(res)], capture_output=True, text=True)
    assert proc.returncode == 3, proc.stderr
    results = read_results(res)
    assert len(results) == 5 and np.allclose(results.T_w_c[:, 2, 3], np.arange(5))
    # Killed between the appends of frame 5: poses.txt one line ahead, status.jsonl cut mid-line.
    with open(res / "poses.txt", "a") as f:
        f.write("1 0 0 0 0 1 0 0 0 0 1 5\n")
    with open(res / "status.jsonl", "a") as f:
        f.write('{"frame": 5, "sta')
    assert len(read_results(res)) == 5


def test_corrupt_or_missing_results_are_input_errors(tmp_path):
    res = tmp_path / "res"
    write_run(res, np.tile(np.eye(4), (4, 1, 1)))
    lines = (res / "status.jsonl").read_text().splitlines()
    (res / "status.jsonl").write_text("\n".join(lines[:1] + ["{not json"] + lines[2:]) + "\n")
    with pytest.raises(InputError, match="status.jsonl line 2"):
        read_results(res)
    (res / "status.jsonl").write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(InputError, match="disagree on the number of frames"):
        read_results(res)
    (res / "timing.csv").unlink()
    with pytest.raises(InputError, match="timing.csv"):
        read_results(res)
    with pytest.raises(InputError, match="does not exist"):
        read_results(tmp_path / "nowhere")


# ---------------------------------------------------------------- dynaslam2 eval


def make_sequence(seq, T_w_c, with_gt=True):
    """A tiny sequence in the real KITTI odometry layout (calib P0/P1, image_0/, image_1/, poses.txt)."""
    for side in ("image_0", "image_1"):
        (seq / side).mkdir(parents=True)
        for i in range(len(T_w_c)):
            cv2.imwrite(str(seq / side / f"{i:06d}.png"), np.full((12, 16), 40 + i, np.uint8))
    K = "100.0 0.0 7.5 {} 0.0 100.0 5.5 0.0 0.0 0.0 1.0 0.0"
    (seq / "calib.txt").write_text(f"P0: {K.format(0.0)}\nP1: {K.format(-54.0)}\n")
    (seq / "times.txt").write_text("".join(f"{0.1 * i:.6e}\n" for i in range(len(T_w_c))))
    if with_gt:
        (seq / "poses.txt").write_text("".join(" ".join(f"{v:.9e}" for v in T[:3].ravel()) + "\n" for T in T_w_c))


@pytest.fixture
def seq_and_run(tmp_path):
    rng = np.random.default_rng(10)
    T_gt = drive(20, rng)
    T_est = perturbed(T_gt, rng, t_sigma=0.01, r_sigma=0.002)
    make_sequence(tmp_path / "seq", T_gt)
    states = ["init"] + ["ok"] * 9 + ["lost", "lost"] + ["relocalized"] + ["ok"] * 7
    write_run(tmp_path / "res", T_est, states, total_ms=50.0)
    return tmp_path / "seq", tmp_path / "res", T_gt, T_est


def test_cli_eval_prints_a_table_and_writes_metrics_json(seq_and_run, capsys):
    seq, res, T_gt, T_est = seq_and_run
    assert main(["eval", str(seq), str(res)]) == 0
    out = capsys.readouterr().out
    m = json.loads((res / "metrics.json").read_text())
    ref_ate, ref_rpe = ate(T_est, T_gt), rpe(T_est, T_gt)
    # poses.txt holds the estimate rounded to the KITTI text precision: compare at that level.
    assert abs(m["ego"]["ate_rmse_m"] - ref_ate["rmse_m"]) < 1e-5
    assert abs(m["ego"]["rpe_t_m_per_frame"] - ref_rpe["t_rmse_m"]) < 1e-5
    assert abs(m["ego"]["rpe_r_deg_per_frame"] - ref_rpe["r_rmse_deg"]) < 1e-3
    assert m["ego"]["frames"] == 20 and m["ego"]["lost_frames"] == 2
    assert m["timing"]["median_ms"]["total"] == pytest.approx(50.0 + 9.5, abs=1e-3)
    assert m["timing"]["median_ms"]["tracking"] == pytest.approx(5.0) and m["timing"]["median_ms"]["boxes"] == 0.0
    assert m["timing"]["fps"] == pytest.approx(1000.0 * 20 / sum(50.0 + i for i in range(20)), rel=1e-4)
    assert m == json.loads(json.dumps(evaluate(seq, res)))
    for key in ("ego.ate_rmse_m", "ego.rpe_t_m_per_frame", "ego.rpe_r_deg_per_frame", "ego.lost_frames",
                "timing.median_ms.local_ba", "timing.fps"):
        assert key in out
    assert format_table(m) in out
    assert main(["eval", str(seq), str(res), "--json", str(seq / "m.json")]) == 0
    assert json.loads((seq / "m.json").read_text()) == m


def test_eval_matches_evo_through_the_files_on_kitti_06(tmp_path):
    if not (KITTI_06 / "poses.txt").is_file():
        pytest.skip(f"real KITTI odometry 06 clip not found at {KITTI_06}")
    T_gt = read_poses(KITTI_06 / "poses.txt")
    write_run(tmp_path / "res", perturbed(T_gt, np.random.default_rng(11), t_sigma=0.01, r_sigma=0.002))
    m = evaluate(KITTI_06, tmp_path / "res")
    T_est = read_results(tmp_path / "res").T_w_c
    ape, rpes = evo_reference(T_est, T_gt)
    assert abs(m["ego"]["ate_rmse_m"] - ape.get_statistic(StatisticsType.rmse)) < TOL
    assert abs(m["ego"]["rpe_t_m_per_frame"] - rpes["t"].get_statistic(StatisticsType.rmse)) < TOL
    assert abs(m["ego"]["rpe_r_deg_per_frame"] - rpes["r"].get_statistic(StatisticsType.rmse)) < TOL
    assert m["ego"]["frames"] == 51 and m["ego"]["lost_frames"] == 0


def run_cli_error(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dynaslam2 eval: error:") and len(err.splitlines()) == 1, err
    return err


def test_cli_eval_bad_input_is_one_line_and_exit_2(seq_and_run, tmp_path, capsys):
    seq, res, T_gt, T_est = seq_and_run
    write_run(tmp_path / "short", T_est[:15])
    assert "15 frames" in run_cli_error(["eval", str(seq), str(tmp_path / "short")], capsys)
    (res / "poses.txt").unlink()
    assert "poses.txt" in run_cli_error(["eval", str(seq), str(res)], capsys)
    make_sequence(tmp_path / "no_gt", T_gt, with_gt=False)
    write_run(tmp_path / "res2", T_est)
    assert "poses.txt" in run_cli_error(["eval", str(tmp_path / "no_gt"), str(tmp_path / "res2")], capsys)
    assert not (tmp_path / "res2" / "metrics.json").exists()
    bad_json = tmp_path / "missing_dir" / "m.json"
    assert "cannot write metrics file" in run_cli_error(["eval", str(seq), str(tmp_path / "res2"), "--json",
                                                         str(bad_json)], capsys)
