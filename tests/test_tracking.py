"""Unit tests of the map bookkeeping, the frontend's mode switch and camera tracking pieces."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dynaslam2.classes import CLASS_IDS
from dynaslam2.config import load_config
from dynaslam2.features.orb import Keypoints
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse, make_pose, so3_exp
from dynaslam2.io.types import FrameData
from dynaslam2.map.keyframe import KeyFrame
from dynaslam2.map.map import Map
from dynaslam2.map.map_point import descriptor_distances, distinctive_descriptors
from dynaslam2.tracking.camera import rigid
from dynaslam2.tracking.frontend import FrameBuilder

KITTI06 = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti-odometry-06"
CAMERA = StereoCamera(500.0, 500.0, 319.5, 239.5, 0.5, 640, 480)


def _keyframe(kf_id: int, n: int, rng: np.random.Generator, stereo: bool = True) -> KeyFrame:
    kp = Keypoints(
        rng.uniform(0, 600, (n, 2)).astype(np.float32), rng.integers(0, 4, n).astype(np.int32),
        rng.uniform(0, 360, n).astype(np.float32), np.ones(n, np.float32),
        rng.integers(0, 256, (n, 32)).astype(np.uint8),
    )
    u_right = (kp.uv[:, 0] - 10.0) if stereo else np.full(n, -1.0)
    return KeyFrame(kf_id, kf_id, 0.1 * kf_id, np.eye(4), kp, u_right.astype(float), np.full(n, 5.0),
                    np.zeros(n, np.int64), np.zeros(n, np.int64), np.ones(n, bool), 20.0)


def test_observations_covisibility_and_fusion():
    rng = np.random.default_rng(0)
    m = Map()
    kfs = [_keyframe(i, 40, rng, stereo=(i != 2)) for i in range(3)]
    for kf in kfs:
        m.add_keyframe(kf)
    ids = m.add_points(kfs[0], np.arange(30), rng.normal(size=(30, 3)))
    m.add_observations(kfs[1], np.arange(20), ids[:20])  # kf1 shares 20 points with kf0
    m.add_observations(kfs[2], np.arange(10), ids[10:20])  # kf2 (mono) shares 10 with both
    assert m.points.n_obs[ids[0]] == 4  # two stereo observations
    assert m.points.n_obs[ids[15]] == 5  # stereo + stereo + mono
    for kf in kfs:
        m.update_connections(kf, min_weight=5)
    assert m.covisibility[0] == {1: 20, 2: 10}
    assert m.covisible(0) == [1, 2]
    # Fuse point 25 (seen by kf0 only) into point 0 (kf0 and kf1): kf0 already sees 0, so its
    # observation of 25 is dropped; counters add up.
    vis_before = m.points.n_visible[ids[0]] + m.points.n_visible[ids[25]]
    m.replace_points(np.array([ids[25]]), np.array([ids[0]]))
    assert not m.points.alive[ids[25]] and m.points.replaced_by[ids[25]] == ids[0]
    assert kfs[0].point_ids[25] == -1 and m.points.n_obs[ids[0]] == 4
    assert m.points.n_visible[ids[0]] == vis_before
    assert m.points.resolve(np.array([ids[25], ids[1], -1])).tolist() == [ids[0], ids[1], -1]
    # Fuse point 12 into a new point seen only by a fresh keyframe: observations move over.
    kf3 = _keyframe(3, 40, rng)
    m.add_keyframe(kf3)
    new = m.add_points(kf3, np.array([5]), np.zeros((1, 3)))
    m.replace_points(np.array([ids[12]]), new)
    kf_obs, pt_obs, kp_obs = m.observers(new)
    assert sorted(kf_obs.tolist()) == [0, 1, 2, 3]
    assert kfs[2].point_ids[2] == new[0] and m.points.n_obs[new[0]] == 2 + 2 + 2 + 1
    # Culling removes the point from every keyframe.
    m.cull_points(ids[:5])
    assert np.all(kfs[0].point_ids[:5] == -1) and np.all(kfs[1].point_ids[:5] == -1)
    assert np.all(m.points.n_obs[ids[:5]] == 0)
    m.erase_keyframe(kfs[2])
    assert 2 not in m.covisibility[0] and 2 not in m.keyframes


def test_distinctive_descriptor_is_the_medoid():
    rng = np.random.default_rng(1)
    base = rng.integers(0, 256, 32).astype(np.uint8)
    near = [base ^ np.eye(32, dtype=np.uint8)[k] for k in range(3)]  # 1 bit away from base
    far = rng.integers(0, 256, 32).astype(np.uint8)
    desc = np.stack([far, near[0], base, near[1], near[2], far, base])
    group = np.array([0, 0, 0, 0, 0, 1, 1])
    rep = distinctive_descriptors(group, desc, 3)
    assert np.array_equal(rep[0], base)
    assert np.array_equal(rep[1], far)  # two descriptors: the first one
    assert np.all(rep[2] == 0)  # empty group
    assert descriptor_distances(near[0], base) == 1


def _textured_frame(instances: np.ndarray | None) -> FrameData:
    rng = np.random.default_rng(2)
    small = rng.integers(0, 256, (60, 80)).astype(np.uint8)
    import cv2

    left = cv2.resize(small, (640, 480), interpolation=cv2.INTER_CUBIC)
    left = cv2.GaussianBlur(left, (3, 3), 0)
    right = np.roll(left, -8, axis=1)  # constant disparity of 8 px
    return FrameData(0, 0.0, left, right, None, instances)


def test_modes_drop_or_flag_features_on_dynamic_instances():
    instances = np.zeros((480, 640), np.uint16)
    instances[100:300, 200:400] = CLASS_IDS["car"] * 1000 + 1
    data = _textured_frame(instances)

    def build(mode, *overrides):
        cfg = load_config(None, [f"mode={mode}", "orb.n_features=800", "tracking.mask_dilation_px=4", *overrides])
        return FrameBuilder(cfg, CAMERA).build(data, {})

    static, masked, dynamic = build("static"), build("masked"), build("dynamic", "objects.n_features=0")
    # The box dilated by 4 px, with the half pixel of keypoint rounding.
    inside = lambda f: ((f.keypoints.uv[:, 0] >= 195.5) & (f.keypoints.uv[:, 0] < 403.5)  # noqa: E731
                        & (f.keypoints.uv[:, 1] >= 95.5) & (f.keypoints.uv[:, 1] < 303.5))
    assert inside(static).sum() > 50 and static.static.all()
    col, row = np.rint(static.keypoints.uv[:, 0]), np.rint(static.keypoints.uv[:, 1])
    on_car = (col >= 200) & (col < 400) & (row >= 100) & (row < 300)
    assert np.array_equal(static.class_id, np.where(on_car, CLASS_IDS["car"], 0))
    assert np.array_equal(static.instance_id, np.where(on_car, CLASS_IDS["car"] * 1000 + 1, 0))
    assert inside(masked).sum() == 0 and len(masked) > 0.8 * len(static)  # the budget moves elsewhere
    assert np.array_equal(dynamic.keypoints.uv, static.keypoints.uv)  # one pass: the car keeps what falls on it
    assert not dynamic.static[on_car].any() and dynamic.static[~inside(dynamic)].all()
    # objects.n_features: masked mode's keypoints, then the car's own pass (its budget on levels 0..2, only on the
    # car).
    separate = build("dynamic", "objects.n_features=150", "objects.features_max_level=2")
    n = len(masked)
    assert np.array_equal(separate.keypoints.uv[:n], masked.keypoints.uv) and separate.static[:n].all()
    col, row = np.rint(separate.keypoints.uv[n:, 0]), np.rint(separate.keypoints.uv[n:, 1])
    assert 50 <= len(col) <= 150 and np.all((col >= 200) & (col < 400) & (row >= 100) & (row < 300))
    assert set(separate.keypoints.octave[n:].tolist()) == {0, 1, 2}
    assert not separate.static[n:].any() and np.all(separate.instance_id[n:] == CLASS_IDS["car"] * 1000 + 1)
    assert np.mean(separate.depth[n:] > 0) > 0.5  # stereo-matched with the first pass's keypoints
    # Stereo works on the shifted image: depth = bf / 8.
    d = static.depth[static.depth > 0]
    assert len(d) > 100 and np.median(np.abs(d - CAMERA.bf / 8.0)) < 0.05 * CAMERA.bf / 8.0


def test_masked_descriptors_of_an_object_ignore_the_background_behind_it():
    """objects.masked_descriptors: the same textured car in front of two different backgrounds. The
    keypoints found at the same place on the car in both frames, within a patch of its outline, get the
    same orientation and descriptor with the background blanked; without, the background changes most of
    them. Static keypoints and depths are not touched."""
    import cv2

    rng = np.random.default_rng(5)

    def texture() -> np.ndarray:
        small = rng.integers(0, 256, (60, 80)).astype(np.uint8)
        return cv2.GaussianBlur(cv2.resize(small, (640, 480), interpolation=cv2.INTER_CUBIC), (3, 3), 0)

    car, backgrounds = texture(), [texture(), texture()]
    instances = np.zeros((480, 640), np.uint16)
    instances[100:300, 200:400] = CLASS_IDS["car"] * 1000 + 1
    frames = {}
    for masked in (False, True):
        cfg = load_config(None, ["mode=dynamic", "orb.n_features=1000", f"objects.masked_descriptors={masked}"])
        for k, background in enumerate(backgrounds):
            left = np.where(instances > 0, car, background)
            frames[masked, k] = FrameBuilder(cfg, CAMERA).build(
                FrameData(0, 0.0, left, np.roll(left, -8, axis=1), None, instances), {})

    def outline_pairs(a, b) -> tuple[np.ndarray, np.ndarray]:
        """Indices of the car keypoints at the same place and level in frames a and b whose level patch
        reaches the car's outline."""
        where = lambda f: {(float(u), float(v), int(o)): i  # noqa: E731
                           for i, ((u, v), o) in enumerate(zip(f.keypoints.uv, f.keypoints.octave))}
        ka, kb = where(a), where(b)
        ia, ib = np.array([(ka[k], kb[k]) for k in ka.keys() & kb.keys() if a.instance_id[ka[k]] > 0]).T
        u, v = a.keypoints.uv[ia].T
        reach = 16 * 1.2 ** a.keypoints.octave[ia]  # half patch at the keypoint's level, in level-0 pixels
        near = (u < 200 + reach) | (u > 400 - reach) | (v < 100 + reach) | (v > 300 - reach)
        assert near.sum() >= 10
        return ia[near], ib[near]

    a, b = frames[True, 0], frames[True, 1]
    ia, ib = outline_pairs(a, b)
    np.testing.assert_array_equal(a.keypoints.desc[ia], b.keypoints.desc[ib])
    np.testing.assert_array_equal(a.keypoints.angle[ia], b.keypoints.angle[ib])
    pa, pb = frames[False, 0], frames[False, 1]
    ja, jb = outline_pairs(pa, pb)
    assert np.any(pa.keypoints.desc[ja] != pb.keypoints.desc[jb], axis=1).mean() > 0.5
    for k in range(2):  # what blanking leaves alone: the static keypoints' descriptors and every depth
        f, g = frames[True, k], frames[False, k]
        np.testing.assert_array_equal(f.keypoints.uv, g.keypoints.uv)
        np.testing.assert_array_equal(f.keypoints.desc[f.static], g.keypoints.desc[g.static])
        np.testing.assert_array_equal(f.depth, g.depth)


def test_rigid_projects_onto_se3():
    R = so3_exp(np.array([0.1, -0.2, 0.3]))
    T = make_pose(R * (1 + 1e-4), np.array([1.0, 2.0, 3.0]))
    T_r = rigid(T)
    assert np.allclose(T_r[:3, :3] @ T_r[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.allclose(T_r[:3, :3], R, atol=1e-3) and np.allclose(T_r[:3, 3], [1, 2, 3])


@pytest.mark.skipif(not KITTI06.is_dir(), reason=f"real KITTI clip not found at {KITTI06}")
def test_tracks_first_frames_against_kitti_ground_truth():
    """Map from frame 0, then frame 1 from the reference keyframe (no velocity yet) and frame 2 by the
    motion model: within 5 cm / 0.5 deg of KITTI's ground truth after ~2.4 m (we measure ~0.26 deg of yaw
    against the GT here, also seen with OpenCV's essential matrix on these frames)."""
    from dynaslam2.io.sequence import open_sequence
    from dynaslam2.system import System
    from dynaslam2.geometry.se3 import so3_log

    seq = open_sequence(KITTI06)
    system = System(load_config(None, ["mode=static"]), seq.camera)
    states = [system.process(seq[i]).state for i in (0, 1)]
    est3 = system.process(seq[2])
    assert states == ["init", "ok"] and est3.state == "ok"
    gt = seq.gt_T_w_c
    d_est = est3.T_w_c  # world = frame 0
    d_gt = inverse(gt[0]) @ gt[2]
    assert np.linalg.norm(d_est[:3, 3] - d_gt[:3, 3]) < 0.05
    assert np.degrees(np.linalg.norm(so3_log(d_est[:3, :3].T @ d_gt[:3, :3]))) < 0.5
    assert est3.n_static_matches >= 100


def test_rgbd_frames_take_depth_from_the_depth_image():
    """No right image: depth at each keypoint from the depth image and a virtual right coordinate."""
    data = _textured_frame(None)
    depth = np.full((480, 640), 5.0, np.float32)
    depth[:, :100] = 0.0  # no depth there
    rgbd = FrameData(0, 0.0, data.left, None, depth, None)
    frame = FrameBuilder(load_config(None, ["mode=static", "orb.n_features=500"]), CAMERA).build(rgbd, {})
    has = np.rint(frame.keypoints.uv[:, 0]) >= 100
    assert has.sum() > 100 and np.all(frame.depth[has] == 5.0) and np.all(frame.depth[~has] < 0)
    assert np.allclose(frame.u_right[has], frame.keypoints.uv[has, 0] - CAMERA.bf / 5.0, atol=1e-4)
    with pytest.raises(Exception, match="right image or a depth image"):
        FrameBuilder(load_config(None, ["mode=static"]), CAMERA).build(FrameData(0, 0.0, data.left), {})
