"""End-to-end sequence generation through the CLI: validity, determinism, knobs, bad input, crash safety."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynaslam2.cli import main
from dynaslam2.io.sequence import open_sequence
from dynaslam2.geometry.camera import StereoCamera
from sim.groundtruth import GroundTruth
from sim.render import StereoRenderer
from sim.scenarios import SCENARIOS, load_scenario
from sim.world import build_world, camera_intrinsics

SMALL = "160x120"


def simulate(out: Path, *args: str) -> int:
    return main(["simulate", "--quiet", "--out", str(out), "--size", SMALL, *args])


def file_hashes(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_every_scenario_gives_a_valid_sequence(scenario, tmp_path):
    out = tmp_path / scenario
    assert simulate(out, "--scenario", scenario, "--frames", "3") == 0
    seq = open_sequence(out)
    assert len(seq) == 3 and seq.meta["complete"] is True
    assert seq.meta["scenario"]["name"] == scenario
    assert seq.camera.width == 160 and seq.camera.height == 120
    n_objects = 0
    for i in range(3):
        frame = seq[i]
        assert frame.left.shape == frame.right.shape == (120, 160, 3)
        assert frame.depth.shape == frame.instances.shape == (120, 160)
        assert frame.depth.max() > 0
        objects = seq.gt_objects(i)
        ids = set(np.unique(frame.instances).tolist()) - {0}
        assert len(ids) == len(objects)  # every listed object is visible, every visible actor listed
        for obj in objects:
            assert 0 < obj.visible_fraction <= 1 and 0 <= obj.truncation <= 1 and obj.occlusion in (0, 1, 2)
        n_objects += len(objects)
    assert n_objects > 0
    np.testing.assert_allclose(seq.gt_T_w_c[0], np.eye(4), atol=1e-12)  # world = left camera at frame 0


def test_same_seed_same_bytes_different_seed_different_scene(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for out, seed in ((a, "5"), (b, "5"), (c, "6")):
        assert simulate(out, "--frames", "3", "--seed", seed) == 0
    ha, hb, hc = file_hashes(a), file_hashes(b), file_hashes(c)
    assert "meta.json" in ha and len(ha) == 3 * 4 + 6
    assert ha == hb
    differing = {k for k in ha if ha[k] != hc.get(k)}
    assert {"image_02/000000.png", "image_03/000000.png", "depth/000000.png", "objects.jsonl"} <= differing


def _objects(out: Path) -> list:
    seq = open_sequence(out)
    return [obj for i in range(len(seq)) for obj in seq.gt_objects(i)]


def _visible_fractions(scenario: str, seed: int, occlusion: float) -> list[float]:
    """Visible fractions of the listed GT objects over 10 frames at 320x240 (world + renderer + GT, no files)."""
    cfg = load_scenario(scenario, ["frames=10", "image_size=320x240", "texture_px=64", f"seed={seed}",
                                   f"occlusion={occlusion}"])
    world = build_world(cfg)
    intrinsics = camera_intrinsics(cfg)
    gt = GroundTruth(world, StereoCamera(*intrinsics, cfg.baseline, *cfg.image_size))
    fractions = []
    with StereoRenderer(world, *cfg.image_size) as renderer:
        for i in range(cfg.frames):
            t = i / cfg.fps
            world.set_time(t)
            T_w_c, T_m_c = gt.camera_pose(t)
            r = renderer.render(T_m_c, intrinsics, right=False, depth=False)
            fractions += [o.visible_fraction for o in gt.objects(t, T_w_c, r.visible_px, r.amodal_px, r.box2d)]
    return fractions


@pytest.mark.parametrize("scenario, seed", [("traffic", 1), ("traffic", 2), ("traffic", 3), ("following", 1),
                                            ("static", 2)])
def test_occlusion_knob_lowers_visible_fraction(scenario, seed):
    """occlusion=1 hides clearly more of the listed objects than occlusion=0 (objects partly hidden, not
    only fully hidden ones dropped from the list)."""
    low, high = (_visible_fractions(scenario, seed, occ) for occ in (0.0, 1.0))
    assert np.mean(high) < np.mean(low) - 0.05, (np.mean(low), np.mean(high))
    assert len(high) >= 0.75 * len(low), (len(low), len(high))  # about as many objects listed


def test_object_speed_knob_raises_gt_speeds(tmp_path):
    speeds = {}
    for scale in ("0.5", "2.0"):
        out = tmp_path / f"speed{scale}"
        assert simulate(out, "--frames", "3", "--seed", "4", "--set", f"object_speed={scale}") == 0
        moving = [np.linalg.norm(obj.v_w) for obj in _objects(out) if np.linalg.norm(obj.v_w) > 0]
        assert moving
        speeds[scale] = float(np.mean(moving))
    assert speeds["2.0"] > 2.0 * speeds["0.5"], speeds


def test_depth_off_writes_no_depth(tmp_path):
    out = tmp_path / "nodepth"
    assert simulate(out, "--frames", "2", "--set", "depth=false") == 0
    assert not (out / "depth").exists()
    seq = open_sequence(out)
    assert len(seq) == 2 and seq[1].depth is None


def test_render_settings_reach_the_renderer_and_meta(tmp_path):
    """`--render-set msaa_samples=0` renders aliased colour images: the labels and depth stay the same bytes,
    the colour images change, and meta.json records the setting."""
    smooth, aliased = tmp_path / "smooth", tmp_path / "aliased"
    assert simulate(smooth, "--frames", "2") == 0
    assert simulate(aliased, "--frames", "2", "--render-set", "msaa_samples=0") == 0
    a, b = file_hashes(smooth), file_hashes(aliased)
    for name in a:
        if name.startswith(("instances", "depth")):
            assert a[name] == b[name], name
    assert any(a[n] != b[n] for n in a if n.startswith("image_0")), "colour images unchanged by msaa_samples=0"
    assert json.loads((smooth / "meta.json").read_text())["render"]["msaa_samples"] == 4
    assert json.loads((aliased / "meta.json").read_text())["render"]["msaa_samples"] == 0


@pytest.mark.parametrize("args, words", [
    (["--scenario", "nosuch"], "unknown scenario"),
    (["--set", "nosuch_knob=1"], "nosuch_knob"),
    (["--set", "fps=-1"], "fps"),
    (["--frames", "0"], "frames"),
    (["--size", "10x10"], "image_size"),
    (["--set", "occlusion=2"], "occlusion"),
    (["--render-set", "msaa=0"], "msaa"),
    (["--render-set", "msaa_samples=-1"], "msaa_samples"),
    (["--render-set", "msaa_samples"], "--render-set"),
])
def test_bad_input_is_one_line_exit_2_nothing_written(args, words, tmp_path, capsys):
    out = tmp_path / "seq"
    assert simulate(out, "--frames", "2", *args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err and err.startswith("dynaslam2 simulate: error:")
    assert not out.exists()


def test_non_empty_output_needs_overwrite(tmp_path, capsys):
    out = tmp_path / "seq"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert simulate(out, "--frames", "2") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not empty" in err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    # A previous sequence is replaced with --overwrite.
    seq_dir = tmp_path / "prev"
    assert simulate(seq_dir, "--frames", "2") == 0
    assert simulate(seq_dir, "--frames", "2") == 2
    assert simulate(seq_dir, "--frames", "3", "--overwrite") == 0
    assert len(open_sequence(seq_dir)) == 3


def test_unwritable_output_path(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    assert simulate(blocker / "seq", "--frames", "2") == 2
    assert capsys.readouterr().err.count("\n") == 1
    if os.geteuid() != 0:  # root may write anywhere: permission bits only bind other users
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        assert simulate(locked / "seq", "--frames", "2") == 2
        assert capsys.readouterr().err.count("\n") == 1
        assert not any(locked.iterdir())


def test_crash_mid_sequence_keeps_the_frames_written(tmp_path, monkeypatch):
    crash_at = 3
    original = StereoRenderer.render
    calls = {"n": 0}

    def failing_render(self, *args, **kwargs):
        if calls["n"] == crash_at:
            raise RuntimeError("simulated renderer crash")
        calls["n"] += 1
        return original(self, *args, **kwargs)

    monkeypatch.setattr(StereoRenderer, "render", failing_render)
    out = tmp_path / "seq"
    with pytest.raises(RuntimeError, match="simulated renderer crash"):
        simulate(out, "--frames", "6")
    seq = open_sequence(out)
    assert len(seq) == crash_at
    assert seq.meta["complete"] is False
    for i in range(crash_at):
        assert seq[i].left.shape == (120, 160, 3)
        seq.gt_objects(i)
    assert not any(p.name.endswith(".tmp") for p in out.rglob("*"))


def test_preview_video_and_contact_sheet(tmp_path):
    out = tmp_path / "seq"
    assert simulate(out, "--frames", "4", "--preview") == 0
    video = cv2.VideoCapture(str(out / "preview.mp4"))
    n, size = 0, None
    while True:
        ok, image = video.read()
        if not ok:
            break
        n, size = n + 1, image.shape
    assert n == 4 and size == (120, 160, 3)
    sheet = cv2.imread(str(out / "preview.png"))
    assert sheet is not None and sheet.shape[1] >= 4 * 160 // 2
    assert json.loads((out / "meta.json").read_text())["complete"] is True


def test_bench_sim_runs(capsys):
    assert main(["bench", "sim", "--quiet", "--frames", "2", "--sizes", SMALL, "--render-set", "msaa_samples=0"]) == 0
    table = capsys.readouterr().out
    assert "160x120" in table and "fps" in table and "msaa_samples 0" in table
