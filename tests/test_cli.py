"""The `dynaslam2` command as a newcomer meets it: help, the demo, and errors."""

import json

import pytest

from dynaslam2.cli import DEMO_MODE, main


@pytest.mark.parametrize("command", ["simulate", "run", "eval", "demo", "sweep", "bench"])
def test_every_subcommand_explains_itself(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert "usage: dynaslam2 " + command in capsys.readouterr().out


def test_no_subcommand_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "simulate" in capsys.readouterr().out


def test_demo_simulates_runs_slam_and_prints_scores(tmp_path, capsys):
    pytest.importorskip("mujoco")
    assert main(["--quiet", "demo", "--frames", "8", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    seq, res = tmp_path / "sequence", tmp_path / f"results-{DEMO_MODE}"
    assert (seq / "preview.mp4").stat().st_size > 0 and (seq / "preview.png").stat().st_size > 0
    metrics = json.loads((res / "metrics.json").read_text())
    assert metrics["ego"]["frames"] == 8
    assert "ego.ate_rmse_m" in out and "per_track" not in out
