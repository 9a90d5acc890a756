"""Sequence writer/reader: round trip of our layout, real KITTI odometry, KITTI tracking layout, bad input."""

from __future__ import annotations

import json
import math
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import make_pose, so3_exp
from dynaslam2.io import FrameData, ObjectState, Sequence, SequenceWriter, open_sequence
from dynaslam2.io.kitti import format_tracking_label, object_to_label, read_calib, read_tracking_labels

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
ODOMETRY = DATA / "kitti-odometry-06"
TRACKING = DATA / "kitti-tracking-labels"

W, H = 64, 48
CAMERA = StereoCamera(60.0, 60.0, 31.5, 23.5, 0.54, W, H)


def _frame(i: int, rng) -> FrameData:
    depth = rng.uniform(0.5, 60.0, (H, W)).astype(np.float32)
    depth[0, :5] = 0.0
    depth[1, :5] = np.nan
    depth[2, :5] = 100.0  # beyond the 65.535 m a uint16 in mm holds: written as no depth
    return FrameData(
        index=i,
        timestamp=0.1 * i + 0.0123,
        left=rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
        right=rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
        depth=depth,
        instances=rng.choice(np.array([0, 1001, 2003, 10000], dtype=np.uint16), (H, W)),
    )


def _objects(i: int, T_w_c: np.ndarray) -> list[ObjectState]:
    """A car ahead (upright w.r.t. the camera) and a pedestrian with a velocity and extra data."""
    T_c_car = np.eye(4)
    T_c_car[:3, :3] = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # heading +z_cam
    T_c_car[:3, 3] = (1.5, 0.8, 12.0 + i)
    car = ObjectState(3, "car", T_w_c @ T_c_car, np.array([0.0, 0.0, 8.0]), np.array([0.0, 0.1, 0.0]),
                      (4.2, 1.8, 1.5), visible_fraction=0.7, truncation=0.0, occlusion=1, box2d=(10.5, 12.0, 30.0, 33.25))
    ped = ObjectState(5, "pedestrian", T_w_c @ make_pose(so3_exp(np.array([0.3, 0.2, 0.1])), np.array([-2.0, 0.5, 8.0])),
                      np.array([1.0, 0.2, 0.0]), np.zeros(3), (0.6, 0.7, 1.75), visible_fraction=0.25,
                      truncation=0.6, occlusion=2, box2d=None, extra={"note": "tilted"})
    return [car, ped]


def _poses(n: int) -> np.ndarray:
    return np.stack([make_pose(so3_exp(np.array([0.01 * i, 0.05 * i, 0.0])), np.array([0.1 * i, 0.0, 1.3 * i]))
                     for i in range(n)])


def _write(out: Path, n: int = 4, seed: int = 0, **kwargs) -> tuple[list[FrameData], np.ndarray]:
    rng = np.random.default_rng(seed)
    frames = [_frame(i, rng) for i in range(n)]
    T_w_c = _poses(n)
    with SequenceWriter(out, CAMERA, {"scenario": {"name": "test"}, "seed": seed, "fps": 10}, **kwargs) as writer:
        for i in range(n):
            writer.write_frame(frames[i], T_w_c[i], _objects(i, T_w_c[i]))
    return frames, T_w_c


def test_round_trip_images_poses_objects(tmp_path):
    out = tmp_path / "seq"
    frames, T_w_c = _write(out)
    seq = open_sequence(out)
    assert isinstance(seq, Sequence) and seq.kind == "sim" and len(seq) == 4
    # fx*B goes through text (%.12e): the baseline comes back to ~1e-13 relative.
    assert seq.camera.baseline == pytest.approx(CAMERA.baseline, rel=1e-12)
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy) == (CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy)
    assert (seq.camera.width, seq.camera.height) == (W, H)
    assert seq.meta["complete"] is True and seq.meta["frames"] == 4 and seq.meta["seed"] == 0
    assert seq.meta["image_size"] == [W, H]
    assert np.allclose(seq.gt_T_w_c, T_w_c, rtol=0, atol=1e-8)
    assert np.allclose(seq.timestamps, [f.timestamp for f in frames], rtol=1e-9)
    for i, (back, ref) in enumerate(zip(seq, frames)):
        assert back.index == i and back.timestamp == pytest.approx(ref.timestamp)
        assert back.left.dtype == np.uint8 and np.array_equal(back.left, ref.left)
        assert np.array_equal(back.right, ref.right)
        assert back.instances.dtype == np.uint16 and np.array_equal(back.instances, ref.instances)
        assert back.depth.dtype == np.float32
        valid = np.isfinite(ref.depth) & (ref.depth > 0) & (ref.depth < 65.0)
        assert np.abs(back.depth[valid] - ref.depth[valid]).max() <= 0.0005 + 1e-5  # half a millimetre + float32 rounding
        assert np.all(back.depth[0, :5] == 0) and np.all(back.depth[1, :5] == 0)
        assert np.all(back.depth[2, :5] == 0)
        objects = seq.gt_objects(i)
        for got, want in zip(objects, _objects(i, T_w_c[i]), strict=True):
            assert got.track_id == want.track_id and got.cls == want.cls
            assert np.array_equal(got.T_w_o, want.T_w_o)  # JSON keeps doubles exactly
            assert np.array_equal(got.v_w, want.v_w) and np.array_equal(got.w_w, want.w_w)
            assert got.dims == want.dims and got.box2d == want.box2d and got.extra == want.extra
            assert (got.visible_fraction, got.truncation, got.occlusion) == (
                want.visible_fraction, want.truncation, want.occlusion)
        labels = seq.gt_labels(i)
        assert [format_tracking_label(lb) for lb in labels] == [
            format_tracking_label(object_to_label(o, T_w_c[i], i)) for o in _objects(i, T_w_c[i])]
    assert seq[-1].index == 3
    with pytest.raises(IndexError):
        seq[4]


def test_written_files_are_kitti_shaped(tmp_path):
    out = tmp_path / "seq"
    _frame_list, T_w_c = _write(out, n=2)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["calib.txt", "depth", "image_02", "image_03", "instances", "label_02.txt", "meta.json",
                     "objects.jsonl", "poses.txt", "times.txt"]
    assert sorted(p.name for p in (out / "image_02").iterdir()) == ["000000.png", "000001.png"]
    calib = read_calib(out / "calib.txt")
    assert np.array_equal(calib["P0"], calib["P2"])
    labels = read_tracking_labels(out / "label_02.txt")
    assert [(lb.frame, lb.track_id, lb.type) for lb in labels] == [
        (0, 3, "Car"), (0, 5, "Pedestrian"), (1, 3, "Car"), (1, 5, "Pedestrian")]
    car = labels[0]
    # car centre at (1.5, 0.8, 12) in the camera, 1.5 m high: bottom face 0.75 m lower (larger y).
    assert car.location == pytest.approx((1.5, 1.55, 12.0), abs=1e-6)
    assert car.rotation_y == pytest.approx(-math.pi / 2, abs=1e-6)
    assert labels[1].truncated == 2 and labels[1].box2d == (-1.0, -1.0, -1.0, -1.0)
    depth_png = cv2.imread(str(out / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert depth_png.dtype == np.uint16
    record = json.loads((out / "objects.jsonl").read_text().splitlines()[1])
    assert record["frame"] == 1 and [o["track_id"] for o in record["objects"]] == [3, 5]
    assert set(record["objects"][0]) >= {"track_id", "class", "T_w_o", "v_w", "w_w", "dims", "visible_fraction",
                                         "truncation", "occlusion", "box2d"}


def test_rgb_is_stored_in_rgb_order(tmp_path):
    """An RGB red image is red in the PNG (cv2 reads it back as BGR (0, 0, 255))."""
    out = tmp_path / "seq"
    red = np.zeros((H, W, 3), np.uint8)
    red[..., 0] = 255
    frame = FrameData(0, 0.0, red, red.copy(), np.ones((H, W), np.float32), np.zeros((H, W), np.uint16))
    with SequenceWriter(out, CAMERA, {}) as writer:
        writer.write_frame(frame, np.eye(4), [])
    on_disk = cv2.imread(str(out / "image_02" / "000000.png"))
    assert tuple(on_disk[0, 0]) == (0, 0, 255)
    assert tuple(open_sequence(out)[0].left[0, 0]) == (255, 0, 0)


def test_without_depth(tmp_path):
    out = tmp_path / "seq"
    _write(out, n=2, with_depth=False)
    assert not (out / "depth").exists()
    seq = open_sequence(out)
    assert len(seq) == 2 and seq[1].depth is None and seq.meta["with_depth"] is False


def test_truncated_sequence_reads_complete_prefix(tmp_path):
    out = tmp_path / "seq"
    _write(out, n=5)
    (out / "image_03" / "000004.png").unlink()
    assert len(open_sequence(out)) == 4
    lines = (out / "objects.jsonl").read_text().splitlines(keepends=True)
    (out / "objects.jsonl").write_text("".join(lines[:3]))
    assert len(open_sequence(out)) == 3
    # A line cut by a crash (no newline) does not count.
    pose_lines = (out / "poses.txt").read_text().splitlines(keepends=True)
    (out / "poses.txt").write_text("".join(pose_lines[:2]) + pose_lines[2][:20])
    seq = open_sequence(out)
    assert len(seq) == 2 and seq.gt_T_w_c.shape == (2, 4, 4) and len(seq.timestamps) == 2
    assert seq.gt_labels(2) == [] and seq.gt_objects(1)
    with pytest.raises(IndexError):
        seq.gt_objects(2)


def test_crash_mid_sequence_keeps_frames(tmp_path):
    out = tmp_path / "seq"
    rng = np.random.default_rng(1)
    with pytest.raises(RuntimeError, match="simulated crash"):
        with SequenceWriter(out, CAMERA, {"seed": 1}) as writer:
            for i in range(3):
                writer.write_frame(_frame(i, rng), np.eye(4), [])
            raise RuntimeError("simulated crash")
    seq = open_sequence(out)
    assert len(seq) == 3 and seq.meta["complete"] is False
    assert np.array_equal(seq[2].instances.shape, (H, W))
    assert not [p for p in out.rglob("*.tmp")]


def test_output_folder_checks(tmp_path):
    out = tmp_path / "seq"
    out.mkdir()
    (out / "keep.txt").write_text("user data")
    with pytest.raises(InputError, match=f"output folder {out} is not empty; pass --overwrite"):
        SequenceWriter(out, CAMERA, {})
    with pytest.raises(InputError, match="keep.txt.*refusing to overwrite"):
        SequenceWriter(out, CAMERA, {}, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]  # nothing written, nothing removed

    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    with pytest.raises(InputError, match=f"output path {a_file} is a file"):
        SequenceWriter(a_file, CAMERA, {})
    with pytest.raises(InputError, match=f"{a_file} is a file"):
        SequenceWriter(a_file / "seq", CAMERA, {})
    assert a_file.read_text() == "x"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="uses /proc as an unwritable location")
def test_unwritable_output_location():
    with pytest.raises(InputError, match="/proc/dynaslam2-test-seq"):
        SequenceWriter("/proc/dynaslam2-test-seq", CAMERA, {})


def test_overwrite_replaces_a_previous_sequence(tmp_path):
    out = tmp_path / "seq"
    _write(out, n=4, seed=0)
    (out / "preview.mp4").write_bytes(b"old preview")
    frames, _ = _write(out, n=2, seed=5, overwrite=True)
    seq = open_sequence(out)
    assert len(seq) == 2 and np.array_equal(seq[1].left, frames[1].left)
    assert not (out / "image_02" / "000003.png").exists() and not (out / "preview.mp4").exists()
    with pytest.raises(InputError, match="not empty"):
        _write(out, n=1)


def test_deterministic_bytes(tmp_path):
    _write(tmp_path / "a", n=2, seed=3)
    _write(tmp_path / "b", n=2, seed=3)
    files_a = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    assert files_a == files_b
    for rel in files_a:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


def test_write_frame_rejects_wrong_images(tmp_path):
    rng = np.random.default_rng(0)
    with SequenceWriter(tmp_path / "seq", CAMERA, {}) as writer:
        frame = _frame(0, rng)
        frame.left = frame.left[:, :-1]
        with pytest.raises(ValueError, match="left must be uint8"):
            writer.write_frame(frame, np.eye(4), [])
        with pytest.raises(ValueError, match="expected index 0"):
            writer.write_frame(_frame(1, rng), np.eye(4), [])
    assert len(open_sequence(tmp_path / "seq")) == 0


# ----------------------------------------------------------------------------------------------
# Real KITTI odometry and tracking layouts


@pytest.mark.skipif(not ODOMETRY.is_dir(), reason=f"real KITTI odometry 06 not found at {ODOMETRY}")
def test_real_kitti_odometry_opens():
    seq = open_sequence(ODOMETRY)
    assert seq.kind == "kitti_odometry" and len(seq) == 51
    assert (seq.camera.width, seq.camera.height) == (1226, 370)
    assert seq.camera.baseline == pytest.approx(0.537, abs=0.001)
    assert seq.gt_T_w_c.shape == (51, 4, 4) and np.allclose(seq.gt_T_w_c[0], np.eye(4), atol=1e-9)
    assert seq.timestamps.shape == (51,) and seq.timestamps[0] == 0.0
    frame = seq[50]
    assert frame.left.shape == (370, 1226) and frame.left.dtype == np.uint8
    assert frame.right.shape == (370, 1226)
    assert frame.depth is None and frame.instances is None
    assert frame.timestamp == seq.timestamps[50]
    assert seq.gt_objects(0) == []


def _fake_odometry(root: Path, n: int = 2, right_size=(40, 30), calib_text: str | None = None) -> Path:
    (root / "image_0").mkdir(parents=True)
    (root / "image_1").mkdir()
    for i in range(n):
        cv2.imwrite(str(root / "image_0" / f"{i:06d}.png"), np.full((30, 40), i, np.uint8))
        cv2.imwrite(str(root / "image_1" / f"{i:06d}.png"), np.zeros(right_size[::-1], np.uint8))
    if calib_text is None:
        P0 = "P0: 50 0 20 0 0 50 15 0 0 0 1 0"
        P1 = "P1: 50 0 20 -25 0 50 15 0 0 0 1 0"
        calib_text = f"{P0}\n{P1}\n"
    (root / "calib.txt").write_text(calib_text)
    return root


def test_fake_odometry_without_poses_or_times(tmp_path):
    seq = open_sequence(_fake_odometry(tmp_path / "odo", n=3))
    assert seq.kind == "kitti_odometry" and len(seq) == 3 and seq.gt_T_w_c is None
    assert seq.camera.baseline == pytest.approx(0.5)
    assert np.allclose(seq.timestamps, [0.0, 0.1, 0.2])
    assert seq[2].left[0, 0] == 2


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: (_fake_odometry(p), (p / "calib.txt").unlink()), r"calib.txt: calibration file not found"),
        (lambda p: (_fake_odometry(p), shutil.rmtree(p / "image_1")), r"image_1: missing right images"),
        (lambda p: _fake_odometry(p, right_size=(41, 30)), r"image_1/000000.png: right image is 41x30"),
        (lambda p: _fake_odometry(p, calib_text="P0: 50 0 20 0 0 50 15 0 0 0 1 0\nP1: 50 0 20 nan 0 50 15 0 0 0 1 0\n"),
         r"calib.txt, line 2: non-finite"),
        (lambda p: _fake_odometry(p, calib_text="P0: 50 0 20 0 0 50 15 0 0 0 1 0\nP1: 52 0 20 -25 0 50 15 0 0 0 1 0\n"),
         r"calib.txt: left and right intrinsics differ"),
        (lambda p: _fake_odometry(p, calib_text="P0: 50 0 20 0 0 50 15 0 0 0 1 0\nP1: 50 0 20 -25 0 50 15 3 0 0 1 0\n"),
         r"calib.txt: P1 is offset"),
        (lambda p: _fake_odometry(p, calib_text="P0: 50 0 20 0 0 50 15 0 0 0 1 0\n"), r"calib.txt: missing projection matrix P1"),
        (lambda p: p.mkdir(), r"not a sequence folder"),
        (lambda p: p.write_text("x"), r"expected a sequence folder, found a file"),
        (lambda p: None, r"sequence folder not found"),
    ],
    ids=["no-calib", "no-image_1", "size-mismatch", "nan-calib", "different-K", "y-offset", "no-P1", "empty",
         "file", "missing"],
)
def test_bad_sequences_raise_input_error(tmp_path, make, message):
    path = tmp_path / "bad"
    make(path)
    with pytest.raises(InputError, match=message) as err:
        open_sequence(path)
    assert str(path) in str(err.value)


@pytest.mark.skipif(not TRACKING.is_dir(), reason=f"real KITTI tracking labels not found at {TRACKING}")
def test_kitti_tracking_layout_with_real_calib_and_labels(tmp_path):
    """A KITTI tracking tree (real calib + labels of 0000, small stand-in images) opens both ways."""
    root = tmp_path / "training"
    n = 4
    for cam in ("image_02", "image_03"):
        (root / cam / "0000").mkdir(parents=True)
        for i in range(n):
            cv2.imwrite(str(root / cam / "0000" / f"{i:06d}.png"), np.zeros((375, 1242, 3), np.uint8))
    (root / "calib").mkdir()
    (root / "label_02").mkdir()
    shutil.copy(TRACKING / "calib" / "0000.txt", root / "calib" / "0000.txt")
    shutil.copy(TRACKING / "label_02" / "0000.txt", root / "label_02" / "0000.txt")
    with pytest.raises(InputError, match="pass the sequence"):
        open_sequence(root)
    for seq in (open_sequence(root, sequence="0000"), open_sequence(root / "image_02" / "0000")):
        assert seq.kind == "kitti_tracking" and len(seq) == n and seq.gt_T_w_c is None
        assert seq.camera.baseline == pytest.approx(0.5327, abs=1e-3)
        assert seq[0].left.shape == (375, 1242, 3)
        labels = seq.gt_labels(0)
        assert [lb.type for lb in labels].count("DontCare") == 2
        objects = seq.gt_objects(0)
        ours = [lb for lb in labels if lb.type in ("Car", "Van", "Truck", "Pedestrian", "Cyclist")]
        assert [o.track_id for o in objects] == [lb.track_id for lb in ours]
        # Objects are in the left (cam2) frame: the box centre projects with K as the label does with P2.
        P2 = read_calib(root / "calib" / "0000.txt")["P2"]
        for obj, lb in zip(objects, ours):
            centre_ref = np.array(lb.location) - [0.0, lb.dims_hwl[0] / 2.0, 0.0]
            uvw = P2 @ np.append(centre_ref, 1.0)
            uv = seq.camera.project(obj.T_w_o[None, :3, 3])[0]
            assert np.allclose(uv, uvw[:2] / uvw[2], atol=0.05)
            assert np.all(np.isnan(obj.v_w)) and obj.extra["kitti_truncated"] == lb.truncated
    assert len(open_sequence(root, sequence="0000").gt_labels(n)) == 0  # labels past the images are dropped


def test_layout_without_meta_and_objects_uses_labels_and_poses(tmp_path):
    """A hand-made layout (no meta.json, no objects.jsonl): GT objects come from label_02 + poses.txt."""
    out = tmp_path / "seq"
    _frames, T_w_c = _write(out, n=3)
    (out / "meta.json").unlink()
    (out / "objects.jsonl").unlink()
    seq = open_sequence(out)
    assert seq.kind == "sim" and len(seq) == 3 and seq.meta == {}
    for i in range(3):
        car_label = next(o for o in seq.gt_objects(i) if o.track_id == 3)
        car = _objects(i, T_w_c[i])[0]
        assert car_label.cls == "car" and car_label.dims == pytest.approx(car.dims)
        assert np.allclose(car_label.T_w_o, car.T_w_o, atol=1e-5)  # labels hold %.6f
        assert car_label.box2d == car.box2d and car_label.occlusion == car.occlusion


def test_meta_image_size_must_match_images(tmp_path):
    out = tmp_path / "seq"
    _write(out, n=1)
    meta = json.loads((out / "meta.json").read_text())
    meta["image_size"] = [W + 1, H]
    (out / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=f"{out / 'image_02' / '000000.png'}: image is {W}x{H}"):
        open_sequence(out)


def test_atomic_write_keeps_old_file_on_failure(tmp_path, monkeypatch):
    from dynaslam2.io import atomic

    path = tmp_path / "meta.json"
    atomic.write_text_atomic(path, "old")

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(atomic.os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        atomic.write_text_atomic(path, "new")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["meta.json"]  # no temporary file left behind


def test_append_log_lines_are_complete(tmp_path):
    from dynaslam2.io.atomic import AppendLog

    log = AppendLog(tmp_path / "log.txt", fsync=True)
    log.write_line("a 1")
    assert (tmp_path / "log.txt").read_text() == "a 1\n"  # flushed before close
    with pytest.raises(ValueError, match="newline"):
        log.write_line("b\nc")
    log.close()
    with AppendLog(tmp_path / "log.txt", mode="a") as log:
        log.write_line("d 2")
    assert (tmp_path / "log.txt").read_text() == "a 1\nd 2\n"


def test_colour_kitti_odometry_moves_gt_to_cam2(tmp_path):
    """image_2/ + image_3/ with P2/P3 (cam2 6 cm right of cam0): GT re-expressed for cam2, world = cam2 at 0."""
    root = tmp_path / "sequences" / "07"
    for cam in ("image_2", "image_3"):
        (root / cam).mkdir(parents=True)
        for i in range(3):
            cv2.imwrite(str(root / cam / f"{i:06d}.png"), np.full((30, 40, 3), (10, 20, 30), np.uint8))
    t2 = np.array([0.06, 0.0, 0.0])  # P2 = K[I|t2]: x_c2 = x_c0 + t2
    K = np.array([[50.0, 0, 20], [0, 50, 15], [0, 0, 1]])
    P2 = np.hstack([K, (K @ t2)[:, None]])
    P3 = np.hstack([K, (K @ (t2 - [0.5, 0, 0]))[:, None]])
    (root / "calib.txt").write_text("".join(f"{k}: {' '.join(map(str, P.ravel()))}\n" for k, P in
                                            (("P0", P2), ("P1", P3), ("P2", P2), ("P3", P3))))
    T_w_c0 = _poses(3)
    (tmp_path / "poses").mkdir()
    np.savetxt(tmp_path / "poses" / "07.txt", T_w_c0[:, :3].reshape(3, 12))
    seq = open_sequence(root)
    assert seq.kind == "kitti_odometry" and len(seq) == 3 and seq.meta["cameras"] == ["image_2", "image_3"]
    assert seq.camera.baseline == pytest.approx(0.5)
    assert seq[0].left.shape == (30, 40, 3) and tuple(seq[0].left[0, 0]) == (30, 20, 10)  # RGB
    assert np.allclose(seq.gt_T_w_c[0], np.eye(4), atol=1e-12)
    T_c2_c0 = np.eye(4)
    T_c2_c0[:3, 3] = t2
    # A point fixed in the world seen from cam2 at frame i: x_c2 = T_c2_c0 T_c0_w x_w, for both conventions.
    X_w0 = np.array([1.0, -2.0, 9.0, 1.0])
    X_w2 = T_c2_c0 @ X_w0
    for i in range(3):
        assert np.allclose(np.linalg.inv(seq.gt_T_w_c[i]) @ X_w2, T_c2_c0 @ np.linalg.inv(T_w_c0[i]) @ X_w0)


def test_corrupt_object_record_is_an_input_error(tmp_path):
    out = tmp_path / "seq"
    _write(out, n=2)
    lines = (out / "objects.jsonl").read_text().splitlines(keepends=True)
    (out / "objects.jsonl").write_text(lines[0] + '{"frame": 1, "objects": [{"track_id": 1}]}\n')
    seq = open_sequence(out)
    assert len(seq.gt_objects(0)) == 2
    with pytest.raises(InputError, match=r"objects.jsonl, line 2: invalid object record"):
        seq.gt_objects(1)
