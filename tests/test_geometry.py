"""SE(3) and stereo camera geometry."""

import numpy as np
import pytest

from dynaslam2.errors import InputError
from dynaslam2.geometry import se3
from dynaslam2.geometry.camera import StereoCamera

RNG = np.random.default_rng(0)


def random_twists(n, rot_scale=1.0):
    return np.concatenate([RNG.normal(size=(n, 3)) * 3, RNG.normal(size=(n, 3)) * rot_scale], -1)


def test_exp_log_round_trip_including_small_and_near_pi_angles():
    xi = random_twists(200)
    axis = RNG.normal(size=(20, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    near_pi = np.concatenate([RNG.normal(size=(20, 3)), axis * (np.pi - 1e-6)], -1)
    tiny = np.concatenate([RNG.normal(size=(20, 3)), RNG.normal(size=(20, 3)) * 1e-9], -1)
    for batch in (xi, near_pi, tiny):
        T = se3.se3_exp(batch)
        assert np.allclose(se3.se3_exp(se3.se3_log(T)), T, atol=1e-7)
    w = RNG.normal(size=(50, 3))
    w *= (np.pi - 1e-3) / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), np.pi)
    assert np.allclose(se3.so3_log(se3.so3_exp(w)), w, atol=1e-9)


def test_so3_exp_matches_opencv_rodrigues():
    import cv2

    for w in RNG.normal(size=(10, 3)):
        R_cv, _ = cv2.Rodrigues(w)
        assert np.allclose(se3.so3_exp(w), R_cv, atol=1e-12)


def test_inverse_compose_transform():
    T = se3.se3_exp(random_twists(10))
    assert np.allclose(se3.inverse(T) @ T, np.eye(4), atol=1e-12)
    X = RNG.normal(size=(30, 3))
    Xh = np.hstack([X, np.ones((30, 1))])
    assert np.allclose(se3.transform(T[0], X), (T[0] @ Xh.T).T[:, :3])
    assert np.allclose(se3.rotation_angle(se3.so3_exp(np.array([0.0, 0.0, 0.3]))), 0.3)


def test_yaw_pose_rotates_about_z():
    T = se3.yaw_pose(1.0, 2.0, 3.0, np.pi / 2)
    assert np.allclose(se3.transform(T, np.array([[1.0, 0.0, 0.0]])), [[1.0, 3.0, 3.0]])


def kitti_like_camera():
    return StereoCamera(fx=718.856, fy=718.856, cx=607.19, cy=185.22, baseline=0.537, width=1241, height=376)


def test_stereo_projection_and_backprojection_are_inverse():
    cam = kitti_like_camera()
    X = np.column_stack([RNG.uniform(-5, 5, 100), RNG.uniform(-2, 2, 100), RNG.uniform(2, 60, 100)])
    uvr = cam.project_stereo(X)
    assert np.allclose(uvr[:, 0] - uvr[:, 2], cam.bf / X[:, 2])
    assert np.allclose(cam.backproject(uvr[:, :2], X[:, 2]), X)


def test_projection_matrices_round_trip_and_validation():
    cam = kitti_like_camera()
    P_l, P_r = cam.projection_matrices()
    assert StereoCamera.from_projection_matrices(P_l, P_r, cam.width, cam.height) == cam
    # KITTI's P2/P3 carry a common offset from cam0: the baseline comes from their difference.
    offset = np.zeros((3, 4))
    offset[:, 3] = [44.857, 0.216, 0.0027]
    shifted = StereoCamera.from_projection_matrices(P_l + offset, P_r + offset, cam.width, cam.height)
    assert shifted.baseline == pytest.approx(cam.baseline)
    bad_y = P_r.copy()
    bad_y[1, 3] = 5.0
    with pytest.raises(InputError, match="rectified"):
        StereoCamera.from_projection_matrices(P_l, bad_y, cam.width, cam.height)
    bad_k = P_r.copy()
    bad_k[0, 0] += 3.0
    with pytest.raises(InputError, match="rectified"):
        StereoCamera.from_projection_matrices(P_l, bad_k, cam.width, cam.height)
    nan = P_l.copy()
    nan[0, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        StereoCamera.from_projection_matrices(nan, P_r, cam.width, cam.height)
    with pytest.raises(InputError, match="baseline"):
        StereoCamera.from_projection_matrices(P_r, P_l, cam.width, cam.height)


def test_stereo_projection_jacobian_matches_numerical_differentiation():
    cam = kitti_like_camera()
    X_c = np.array([[1.5, -0.4, 12.0], [-6.0, 1.2, 4.5], [0.2, 0.1, 40.0]])
    eps = 1e-6
    numeric = np.stack([(cam.project_stereo(X_c + eps * e) - cam.project_stereo(X_c - eps * e)) / (2 * eps)
                        for e in np.eye(3)], axis=-1)
    np.testing.assert_allclose(cam.project_stereo_jacobian(X_c), numeric, rtol=1e-6, atol=1e-6)
