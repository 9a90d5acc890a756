"""KITTI formats against the real files in ../shared/data, and the object <-> label conversion."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse, make_pose, so3_exp
from dynaslam2.io.kitti import (
    TrackingLabel,
    format_tracking_label,
    label_box_corners,
    label_to_object_pose,
    labels_box_corners,
    labels_from_lines,
    object_to_label,
    read_calib,
    read_instance_png,
    read_poses,
    read_times,
    read_tracking_labels,
    reference_to_left,
    stereo_camera_from_calib,
    write_calib,
    write_instance_png,
    write_poses,
)
from dynaslam2.io.types import ObjectState

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
TRACKING = DATA / "kitti-tracking-labels"
ODOMETRY = DATA / "kitti-odometry-06"
needs_tracking = pytest.mark.skipif(not TRACKING.is_dir(), reason=f"real KITTI tracking labels not found at {TRACKING}")
needs_odometry = pytest.mark.skipif(not ODOMETRY.is_dir(), reason=f"real KITTI odometry 06 not found at {ODOMETRY}")


def _label_files():
    return sorted((TRACKING / "label_02").glob("*.txt"))


@needs_tracking
def test_real_tracking_labels_round_trip_text_and_values():
    files = _label_files()
    assert len(files) == 21
    n_lines = 0
    for path in files:
        lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
        labels = read_tracking_labels(path)
        assert len(labels) == len(lines)
        formatted = [format_tracking_label(label) for label in labels]
        assert formatted == lines, path  # identical text, hence identical values when parsed again
        n_lines += len(lines)
    assert n_lines > 60000


def read_tracking_labels_line(line: str) -> TrackingLabel:
    (label,) = labels_from_lines([line])
    return label


def test_result_line_with_score_round_trips():
    line = "3 7 Car 0 1 -1.500000 10.000000 20.000000 110.000000 90.000000 1.500000 1.700000 4.200000 1.000000 1.600000 20.000000 -1.700000 0.875000"
    label = read_tracking_labels_line(line)
    assert label.score == 0.875 and label.track_id == 7 and label.frame == 3
    assert format_tracking_label(label) == line


@needs_tracking
def test_real_tracking_calibs_parse_with_baseline_from_p2_p3():
    for path in sorted((TRACKING / "calib").glob("*.txt")):
        calib = read_calib(path)
        for key in ("P0", "P1", "P2", "P3", "Tr_velo_cam", "Tr_imu_velo"):
            assert calib[key].shape == (3, 4), (path, key)
        assert calib["R_rect"].shape == (3, 3)
        assert np.array_equal(calib["R_rect"], calib["R0_rect"])
        cam = stereo_camera_from_calib(calib, 1242, 375, "P2", "P3", source=str(path))
        # P2/P3 both carry cam2's offset from cam0: the baseline is their difference (~0.53-0.54 m).
        assert 0.52 < cam.baseline < 0.55, (path, cam.baseline)
        cam01 = stereo_camera_from_calib(calib, 1242, 375, "P0", "P1")
        assert cam01.baseline == pytest.approx(-calib["P1"][0, 3] / calib["P1"][0, 0], rel=1e-12)
        assert cam.fx == calib["P2"][0, 0] and cam.cx == calib["P2"][0, 2] and cam.cy == calib["P2"][1, 2]
        # cam2 sits ~6 cm left of the reference camera (cam0): x_cam2 = x_cam0 + (0.06, ., .).
        assert reference_to_left(calib)[0, 3] == pytest.approx(0.06, abs=0.005)


@needs_odometry
def test_real_odometry_calib_baseline():
    calib = read_calib(ODOMETRY / "calib.txt")
    cam = stereo_camera_from_calib(calib, 1226, 370, "P0", "P1")
    assert cam.baseline == pytest.approx(-calib["P1"][0, 3] / calib["P1"][0, 0], rel=1e-12)
    assert cam.baseline == pytest.approx(0.537, abs=0.001)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (707.0912, 707.0912, 601.8873, 183.1104)


@needs_odometry
def test_real_poses_and_times_round_trip(tmp_path):
    T = read_poses(ODOMETRY / "poses.txt")
    assert T.shape == (51, 4, 4)
    assert np.allclose(T[0], np.eye(4), atol=1e-9)
    assert np.allclose(T[:, 3], [0, 0, 0, 1])
    write_poses(tmp_path / "poses.txt", T)
    assert np.array_equal(read_poses(tmp_path / "poses.txt"), T)
    times = read_times(ODOMETRY / "times.txt")
    assert times.shape == (51,) and times[0] == 0.0 and np.all(np.diff(times) > 0.09)


@needs_tracking
def test_real_labels_project_onto_their_2d_boxes():
    """The 3D box of an unoccluded, untruncated Car projected with P2 matches its 2D box (conventions)."""
    ious = []
    for path in _label_files():
        P2 = read_calib(TRACKING / "calib" / path.name)["P2"]
        cars = [lb for lb in read_tracking_labels(path) if lb.type == "Car" and lb.occluded == 0 and lb.truncated == 0]
        if not cars:
            continue
        X = labels_box_corners(cars)  # (N, 8, 3)
        uvw = np.einsum("ij,nkj->nki", P2, np.concatenate([X, np.ones(X.shape[:2] + (1,))], -1))
        uv = uvw[..., :2] / uvw[..., 2:]
        box = np.concatenate([uv.min(1), uv.max(1)], -1).clip(0, [1241, 374, 1241, 374])
        gt = np.array([lb.box2d for lb in cars])
        wh = (np.minimum(box[:, 2:], gt[:, 2:]) - np.maximum(box[:, :2], gt[:, :2])).clip(0)
        inter = wh[:, 0] * wh[:, 1]
        area = lambda b: (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])  # noqa: E731
        ious.append(inter / (area(box) + area(gt) - inter))
    ious = np.concatenate(ious)
    assert len(ious) > 5000
    assert np.mean(ious > 0.7) > 0.95, np.mean(ious > 0.7)


@needs_tracking
def test_real_labels_alpha_matches_rotation_y_and_location():
    """alpha = ry - atan2(x, z), as object_to_label writes it, agrees with KITTI's own alphas."""
    errors = []
    for path in _label_files()[:5]:
        for label in read_tracking_labels(path):
            if label.type == "DontCare":
                continue
            T_w_o, dims = label_to_object_pose(label, np.eye(4))
            obj = ObjectState(label.track_id, "car", T_w_o, np.zeros(3), np.zeros(3), dims)
            alpha = object_to_label(obj, np.eye(4), label.frame).alpha
            errors.append(abs((alpha - label.alpha + math.pi) % (2 * math.pi) - math.pi))
    errors = np.array(errors)
    assert np.median(errors) < 0.01 and np.percentile(errors, 90) < 0.03


def _random_T_w_c(rng) -> np.ndarray:
    return make_pose(so3_exp(rng.normal(size=3)), rng.normal(scale=20.0, size=3))


def _upright_T_c_o(rng) -> np.ndarray:
    """An object upright w.r.t. the camera: up = -y_cam, heading in the camera x-z plane."""
    ry = rng.uniform(-math.pi, math.pi)
    T_c_o = np.eye(4)
    T_c_o[:3, :3] = np.array([[math.cos(ry), math.sin(ry), 0.0], [0.0, 0.0, -1.0], [-math.sin(ry), math.cos(ry), 0.0]])
    T_c_o[:3, 3] = rng.uniform([-15, -1, 3], [15, 3, 60])
    return T_c_o


def test_object_label_round_trip_random_upright_objects():
    rng = np.random.default_rng(7)
    for k in range(200):
        T_w_c = _random_T_w_c(rng)
        T_w_o = T_w_c @ _upright_T_c_o(rng)
        dims = tuple(rng.uniform([0.5, 0.5, 1.0], [12.0, 3.0, 4.0]))
        obj = ObjectState(k, "van", T_w_o, np.zeros(3), np.zeros(3), dims, truncation=0.3, occlusion=2,
                          box2d=(1.0, 2.0, 3.0, 4.0))
        label = object_to_label(obj, T_w_c, frame=5)
        assert label.type == "Van" and label.frame == 5 and label.track_id == k
        assert label.truncated == 1 and label.occluded == 2
        assert label.dims_hwl == (dims[2], dims[1], dims[0])
        assert -math.pi <= label.rotation_y < math.pi and -math.pi <= label.alpha < math.pi
        T_w_o_back, dims_back = label_to_object_pose(label, T_w_c)
        assert np.allclose(T_w_o_back, T_w_o, atol=1e-9)
        assert dims_back == pytest.approx(dims)
        # Through the text format (%.6f) the pose survives to ~1e-6.
        text_label = read_tracking_labels_line(format_tracking_label(label))
        assert np.allclose(label_to_object_pose(text_label, T_w_c)[0], T_w_o, atol=1e-4)


def test_object_to_label_geometry():
    """Bottom-face centre below the box centre; KITTI heading (cos ry, 0, -sin ry); alpha definition."""
    T_c_o = np.eye(4)
    # columns: forward = +z_cam, left = -x_cam, up = -y_cam
    T_c_o[:3, :3] = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    T_c_o[:3, 3] = (2.0, 0.5, 10.0)
    obj = ObjectState(1, "car", T_c_o, np.zeros(3), np.zeros(3), (4.0, 1.8, 1.5))
    label = object_to_label(obj, np.eye(4), 0)
    assert label.location == pytest.approx((2.0, 1.25, 10.0))
    # heading along +z: (cos ry, 0, -sin ry) = (0, 0, 1) -> ry = -pi/2
    assert label.rotation_y == pytest.approx(-math.pi / 2)
    assert label.alpha == pytest.approx(-math.pi / 2 - math.atan2(2.0, 10.0))
    assert label.box2d == (-1.0, -1.0, -1.0, -1.0) and label.truncated == 0
    corners = label_box_corners(label)
    assert np.allclose(corners[0], [2.0 - 0.9, 1.25, 12.0])  # front-left-bottom (KITTI devkit order)
    assert corners[:, 1].max() == pytest.approx(1.25) and corners[:, 1].min() == pytest.approx(-0.25)
    assert np.ptp(corners[:, 2]) == pytest.approx(4.0) and np.ptp(corners[:, 0]) == pytest.approx(1.8)


def test_non_upright_object_uses_projected_heading_and_keeps_centre():
    rng = np.random.default_rng(3)
    T_w_c = _random_T_w_c(rng)
    T_c_o = _upright_T_c_o(rng)
    tilt = make_pose(so3_exp(np.array([0.1, -0.05, 0.0])), np.zeros(3))  # roll/pitch about the object's x, y
    T_w_o = T_w_c @ T_c_o @ tilt
    obj = ObjectState(1, "truck", T_w_o, np.zeros(3), np.zeros(3), (8.0, 2.5, 3.0))
    label = object_to_label(obj, T_w_c, 0)
    heading_c = (inverse(T_w_c) @ T_w_o)[:3, 0]
    assert math.cos(label.rotation_y) * heading_c[2] == pytest.approx(-math.sin(label.rotation_y) * heading_c[0])
    assert math.cos(label.rotation_y) * heading_c[0] - math.sin(label.rotation_y) * heading_c[2] > 0
    T_w_o_back, _ = label_to_object_pose(label, T_w_c)
    assert np.allclose(T_w_o_back[:3, 3], T_w_o[:3, 3], atol=1e-9)


def test_object_to_label_rejects_unknown_class():
    obj = ObjectState(1, "static", np.eye(4), np.zeros(3), np.zeros(3), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="static"):
        object_to_label(obj, np.eye(4), 0)


def test_write_calib_round_trip_and_kitti_shape(tmp_path):
    cam = StereoCamera(500.0, 501.0, 319.5, 239.5, 0.54, 640, 480)
    write_calib(tmp_path / "calib.txt", cam)
    calib = read_calib(tmp_path / "calib.txt")
    assert np.array_equal(calib["P0"], calib["P2"]) and np.array_equal(calib["P1"], calib["P3"])
    assert calib["P1"][0, 3] == pytest.approx(-500.0 * 0.54)
    assert np.array_equal(calib["R_rect"], np.eye(3))
    assert calib["Tr_velo_cam"].shape == (3, 4) and calib["Tr_imu_velo"].shape == (3, 4)
    assert np.allclose(np.linalg.det(calib["Tr_velo_cam"][:, :3]), 1.0)
    for left, right in (("P2", "P3"), ("P0", "P1")):
        back = stereo_camera_from_calib(calib, 640, 480, left, right)
        assert (back.fx, back.fy, back.cx, back.cy, back.width, back.height) == (500.0, 501.0, 319.5, 239.5, 640, 480)
        assert back.baseline == pytest.approx(0.54, rel=1e-12)
    for line in (tmp_path / "calib.txt").read_text().splitlines():
        assert line.split()[0].endswith(":")


def test_read_calib_errors_name_file_and_line(tmp_path):
    path = tmp_path / "calib.txt"
    with pytest.raises(InputError, match="calib.txt: calibration file not found"):
        read_calib(path)
    good = "P0: " + " ".join(["1"] * 12)
    path.write_text(good + "\nP1: 1 2 three 4 5 6 7 8 9 10 11 12\n")
    with pytest.raises(InputError, match=r"calib.txt, line 2: expected numbers"):
        read_calib(path)
    path.write_text(good + "\nP1: 1 2 nan 4 5 6 7 8 9 10 11 12\n")
    with pytest.raises(InputError, match=r"calib.txt, line 2: non-finite"):
        read_calib(path)
    path.write_text(good + "\nP1: 1 2 3\n")
    with pytest.raises(InputError, match=r"calib.txt, line 2: P1 needs 12 numbers"):
        read_calib(path)
    path.write_text("\n")
    with pytest.raises(InputError, match="empty calibration"):
        read_calib(path)


def test_stereo_camera_from_calib_rejects_non_rectified():
    cam = StereoCamera(500.0, 500.0, 320.0, 240.0, 0.5, 640, 480)
    P_left, P_right = cam.projection_matrices()
    bad_k = P_right.copy()
    bad_k[0, 0] = 510.0
    with pytest.raises(InputError, match="intrinsics differ"):
        stereo_camera_from_calib({"P2": P_left, "P3": bad_k}, 640, 480, source="cal.txt")
    y_off = P_right.copy()
    y_off[1, 3] = 500.0 * 0.05  # right camera 5 cm lower: 10% of the baseline
    with pytest.raises(InputError, match="cal.txt: P3 is offset"):
        stereo_camera_from_calib({"P2": P_left, "P3": y_off}, 640, 480, source="cal.txt")
    with pytest.raises(InputError, match="cal.txt: missing projection matrix P3"):
        stereo_camera_from_calib({"P2": P_left}, 640, 480, source="cal.txt")
    swapped = P_left.copy()
    swapped[0, 3] = +250.0
    with pytest.raises(InputError, match="baseline must be positive"):
        stereo_camera_from_calib({"P2": P_left, "P3": swapped}, 640, 480)
    nan = P_right.copy()
    nan[0, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        stereo_camera_from_calib({"P2": P_left, "P3": nan}, 640, 480)


def test_instance_png_round_trip_16bit(tmp_path):
    rng = np.random.default_rng(0)
    ids = rng.choice(np.array([0, 1001, 1002, 2001, 3005, 10000], dtype=np.uint16), size=(37, 53))
    write_instance_png(tmp_path / "ids.png", ids)
    back = read_instance_png(tmp_path / "ids.png")
    assert back.dtype == np.uint16 and np.array_equal(back, ids)
    cv2.imwrite(str(tmp_path / "eight.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(InputError, match="eight.png: expected a 16-bit"):
        read_instance_png(tmp_path / "eight.png")
    with pytest.raises(ValueError):
        write_instance_png(tmp_path / "x.png", ids.astype(np.int32))


def test_read_poses_rejects_bad_lines(tmp_path):
    path = tmp_path / "poses.txt"
    path.write_text(" ".join(["0"] * 12) + "\n" + " ".join(["0"] * 11) + "\n")
    with pytest.raises(InputError, match=r"poses.txt, line 2: expected 12 numbers"):
        read_poses(path)
