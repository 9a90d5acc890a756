"""`dynaslam2 sweep`: the grid's runs, their summary, resuming, bad input, a failing run, parallel backends."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

import dynaslam2.runner
import sim.generate
from dynaslam2.cli import main
from dynaslam2.sweep import SUMMARY_FILE

BASE = ["sweep", "--quiet", "--scenario", "traffic", "--frames", "10", "--size", "320x240", "--seeds", "1"]
GRID = ["--grid", "object_speed=0.5,1.5", "--modes", "dynamic", "static"]


def rows(out: Path) -> list[dict]:
    with open(out / SUMMARY_FILE, newline="") as f:
        return list(csv.DictReader(f))


def estimates(out: Path) -> list[dict]:
    """summary.csv without its timing columns (the estimates and scores: the same wherever they ran)."""
    return [{k: v for k, v in r.items() if not k.startswith("timing.")} for r in rows(out)]


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sweep") / "out"
    assert main([*BASE, *GRID, "--out", str(out)]) == 0
    return out


def test_every_grid_point_and_mode_is_simulated_run_scored_and_tabulated(swept, tmp_path):
    table = rows(swept)
    assert [(r["object_speed"], r["mode"], r["status"]) for r in table] == [
        ("0.5", "dynamic", "ok"), ("0.5", "static", "ok"), ("1.5", "dynamic", "ok"), ("1.5", "static", "ok")]
    for r in table:
        metrics = json.loads((swept / "res" / r["job"] / r["mode"] / "metrics.json").read_text())
        assert float(r["ego.ate_rmse_m"]) == metrics["ego"]["ate_rmse_m"]
        assert (r["objects.tp_ratio"] != "") == (r["mode"] == "dynamic")
    # The sweep's sequence is the one `dynaslam2 simulate` makes from the same scenario, overrides and seed.
    direct = tmp_path / "direct"
    assert main(["simulate", "--quiet", "--scenario", "traffic", "--frames", "10", "--size", "320x240", "--seed", "0",
                 "--set", "object_speed=1.5", "--out", str(direct)]) == 0
    for name in ("poses.txt", "objects.jsonl", "image_02/000009.png", "instances/000009.png"):
        assert (direct / name).read_bytes() == (swept / "seq" / "traffic_object_speed=1.5_s0" / name).read_bytes()


def test_a_rerun_resumes_without_running_again(swept, monkeypatch):
    before = (swept / SUMMARY_FILE).read_text()

    def no_run(*args, **kwargs):
        raise AssertionError("a finished run or a complete sequence was made again")

    monkeypatch.setattr(dynaslam2.runner, "run_sequence", no_run)
    monkeypatch.setattr(sim.generate, "generate_sequence", no_run)
    assert main([*BASE, *GRID, "--out", str(swept)]) == 0
    assert (swept / SUMMARY_FILE).read_text() == before


@pytest.mark.parametrize("args, words", [
    (["--grid", "no_such_field=1,2"], "no_such_field"),
    (["--grid", "object_speed"], "--grid"),
    (["--grid", "slam.objects.no_such_key=1"], "no_such_key"),
    (["--grid", "occlusion=0.5,7"], "occlusion"),
    (["--seeds", "0"], "--seeds"),
])
def test_bad_input_is_one_line_exit_2_nothing_written(args, words, tmp_path, capsys):
    out = tmp_path / "out"
    assert main([*BASE, *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err and err.startswith("dynaslam2 sweep: error:"), err
    assert not out.exists()


def test_another_sweep_or_a_foreign_folder_is_refused(swept, tmp_path, capsys):
    assert main([*BASE, "--grid", "object_speed=0.5,2", "--out", str(swept)]) == 2
    assert "holds another sweep" in capsys.readouterr().err
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    assert main([*BASE, *GRID, "--out", str(foreign)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert [p.name for p in foreign.iterdir()] == ["notes.txt"]


def test_a_failing_run_is_recorded_and_the_others_go_on(tmp_path, monkeypatch, capsys):
    real = dynaslam2.runner.run_sequence

    def flaky(seq, mode, out, **kwargs):
        if mode == "static":
            raise RuntimeError("simulated crash")
        return real(seq, mode, out, **kwargs)

    monkeypatch.setattr(dynaslam2.runner, "run_sequence", flaky)
    out = tmp_path / "out"
    assert main([*BASE, "--grid", "object_speed=1", "--modes", "dynamic", "static", "--out", str(out)]) == 1
    table = rows(out)
    assert table[0]["status"] == "ok" and table[1]["status"].startswith("failed: RuntimeError: simulated crash")
    assert "simulated crash" in capsys.readouterr().err
    monkeypatch.setattr(dynaslam2.runner, "run_sequence", real)  # the rerun completes what failed
    assert main([*BASE, "--grid", "object_speed=1", "--modes", "dynamic", "static", "--out", str(out)]) == 0
    assert [r["status"] for r in rows(out)] == ["ok", "ok"]


def test_parallel_processes_give_the_same_summary(swept, tmp_path):
    out = tmp_path / "out"
    assert main([*BASE, *GRID, "--jobs", "2", "--out", str(out)]) == 0
    assert estimates(out) == estimates(swept)


def test_ray_backend_gives_the_same_summary(swept, tmp_path):
    pytest.importorskip("ray", reason="Ray is optional (pip install ray): the ray backend is tested where it is")
    out = tmp_path / "out"
    assert main([*BASE, *GRID, "--backend", "ray", "--out", str(out)]) == 0
    assert estimates(out) == estimates(swept)
