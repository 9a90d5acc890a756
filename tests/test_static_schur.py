"""The static terms reduced to the cameras (optim/static_schur.py) against gtsam's own linearization
and elimination of the same factors."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from dynaslam2.config import OptimConfig
from dynaslam2.geometry.se3 import inverse
from dynaslam2.optim.gtsam_utils import add_stereo_factors, insert_poses, insert_points
from dynaslam2.optim.reprojection import chi2_thresholds, is_stereo
from dynaslam2.optim.static_schur import square_root, static_schur
from dynaslam2.optim.synthetic import kitti_like_camera
from dynaslam2.optim.synthetic_objects import make_object_window

CAMERA = kitti_like_camera()


@pytest.mark.parametrize("disparity_weight", [None, 3.0])
@pytest.mark.parametrize("robust", [False, True])
def test_reduced_system_and_back_substitution_are_gtsams(robust, disparity_weight):
    """Perturbed window with outliers and monocular observations, no damping: S and s equal the Hessian
    and gradient on the free cameras left by gtsam's elimination of the points (GenericStereoFactor3D /
    projection factors, Huber as gtsam's Robust model; with `disparity_weight` the stereo noise of the object
    terms, eq. 2), and the point steps its back-substitution."""
    cfg = OptimConfig()
    p = make_object_window(np.random.default_rng(3), CAMERA, n_keyframes=6, n_static=300,
                           outlier_fraction=0.05).problem
    mono = np.random.default_rng(4).random(len(p.meas)) < 0.2
    meas = p.meas.copy()
    meas[mono, 2] = -1.0
    n_obs = np.bincount(p.obs_pt, minlength=len(p.X_w))
    n_st = np.bincount(p.obs_pt[is_stereo(meas)], minlength=len(p.X_w))
    use = ((n_obs >= 2) | (n_st >= 1))[p.obs_pt]
    obs_kf, obs_pt, meas, inv_sigma2 = p.obs_kf[use], p.obs_pt[use], meas[use], p.inv_sigma2[use]
    delta2 = chi2_thresholds(meas, cfg.chi2_mono, cfg.chi2_stereo) if robust else None
    free = ~p.fixed
    schur = static_schur(p.T_c_w, free, p.X_w, obs_kf, obs_pt, meas, inv_sigma2, CAMERA, cfg.min_depth, delta2, 0.0,
                         disparity_weight)

    K = len(p.T_c_w)
    point_key = K + schur.points
    values = gtsam.Values()
    insert_poses(values, np.arange(K), inverse(p.T_c_w))
    insert_points(values, point_key, p.X_w[schur.points])
    graph = gtsam.NonlinearFactorGraph()
    key_of_point = np.full(len(p.X_w), -1)
    key_of_point[schur.points] = point_key
    deltas = (np.sqrt(cfg.chi2_mono), np.sqrt(cfg.chi2_stereo)) if robust else (None, None)
    add_stereo_factors(graph, obs_kf, key_of_point[obs_pt], meas, inv_sigma2, CAMERA, *deltas,
                       disparity_weight=disparity_weight)
    bayes_net, rest = graph.linearize(values).eliminatePartialSequential(gtsam.Ordering(point_key.tolist()))
    cams = np.flatnonzero(free)
    H, eta = rest.hessian(gtsam.Ordering(cams.tolist() + np.flatnonzero(~free).tolist()))
    eta = eta.ravel()
    n = 6 * len(cams)
    assert np.array_equal(schur.cams, cams)
    assert np.abs(schur.S - H[:n, :n]).max() < 1e-9 * np.abs(H[:n, :n]).max()
    assert np.abs(schur.s + eta[:n]).max() < 1e-7 * np.abs(eta[:n]).max()

    d_cams = np.random.default_rng(5).normal(0.0, 1e-3, (len(cams), 6))
    given = gtsam.VectorValues()
    for k in range(K):
        given.insert(k, d_cams[np.searchsorted(cams, k)] if free[k] else np.zeros(6))
    solution = bayes_net.optimize(given)
    expected = np.array([solution.at(int(k)) for k in point_key])
    assert np.abs(schur.point_steps(d_cams) - expected).max() < 1e-7 * np.abs(expected).max()


def test_damping_holds_points_without_depth_information():
    """A point seen once, monocular, has no depth information: undamped its block is singular; damped
    (as LM's H_pp + lambda I) it moves only along its ray's normal plane, by a finite step."""
    p = make_object_window(np.random.default_rng(6), CAMERA, n_keyframes=4, n_static=100).problem
    meas = p.meas.copy()
    lonely = np.flatnonzero(np.bincount(p.obs_pt, minlength=len(p.X_w)) == 1)
    assert len(lonely)
    meas[np.isin(p.obs_pt, lonely), 2] = -1.0
    schur = static_schur(p.T_c_w, ~p.fixed, p.X_w, p.obs_kf, p.obs_pt, meas, p.inv_sigma2, CAMERA, 1e-3, None, 1e-4)
    step = schur.point_steps(np.random.default_rng(7).normal(0.0, 1e-3, (len(schur.cams), 6)))
    assert np.all(np.isfinite(step)) and np.all(np.isfinite(schur.S))
    held = np.isin(schur.points, lonely)
    camera_of = np.full(len(p.X_w), -1)
    camera_of[p.obs_pt] = p.obs_kf  # the single camera of each lonely point
    centres = inverse(p.T_c_w)[:, :3, 3]
    rays = p.X_w[schur.points[held]] - centres[camera_of[schur.points[held]]]
    along = np.abs(np.einsum("ij,ij->i", step[held], rays / np.linalg.norm(rays, axis=1, keepdims=True)))
    assert np.all(along < 1e-3 * np.linalg.norm(step[held], axis=1) + 1e-12)


def test_a_singular_point_block_raises():
    """Undamped, a point seen once without depth has a singular block: reduce_static raises LinAlgError (the
    LM of schur_lm.py then raises its damping), not a system of NaNs."""
    p = make_object_window(np.random.default_rng(6), CAMERA, n_keyframes=4, n_static=100).problem
    meas = p.meas.copy()
    meas[np.isin(p.obs_pt, np.flatnonzero(np.bincount(p.obs_pt, minlength=len(p.X_w)) == 1)), 2] = -1.0
    with pytest.raises(np.linalg.LinAlgError):
        static_schur(p.T_c_w, ~p.fixed, p.X_w, p.obs_kf, p.obs_pt, meas, p.inv_sigma2, CAMERA, 1e-3, None, 0.0)


def test_factor_square_root():
    """The factor's rows A, b: A^T A = S and -A^T b = s, by Cholesky when S is positive definite (the fixed
    cameras hold the gauge), by the eigen-decomposition when it is not (here a camera without terms)."""
    p = make_object_window(np.random.default_rng(8), CAMERA, n_keyframes=4, n_static=150).problem
    schur = static_schur(p.T_c_w, ~p.fixed, p.X_w, p.obs_kf, p.obs_pt, p.meas, p.inv_sigma2, CAMERA, 1e-3, None, 1e-4)
    S, s = schur.S.copy(), schur.s.copy()
    S[:6], S[:, :6], s[:6] = 0.0, 0.0, 0.0
    for full, (S_k, s_k) in ((True, (schur.S, schur.s)), (False, (S, s))):
        A, b = square_root(S_k, s_k)
        assert np.abs(A.T @ A - S_k).max() < 1e-9 * np.abs(S_k).max()
        assert np.abs(A.T @ b + s_k).max() < 1e-6 * np.abs(s_k).max()
        assert (len(b) == len(s_k)) == full


def test_factors_by_group_are_the_one_factor_model():
    """StaticSchur.factors on groups of cameras that see no point in common (S zero between them, as the objects
    of eq. 2): the summed errors are the one factor's quadratic model at any poses."""
    p = make_object_window(np.random.default_rng(9), CAMERA, n_keyframes=6, n_static=200).problem
    schur = static_schur(p.T_c_w, ~p.fixed, p.X_w, p.obs_kf, p.obs_pt, p.meas, p.inv_sigma2, CAMERA, 1e-3, None, 1e-4)
    groups = np.arange(len(schur.cams)) % 2
    between = groups[:, None] != groups[None, :]
    schur.S = schur.S * ~np.kron(between, np.ones((6, 6), dtype=bool))  # (the blocks of cameras of two groups)
    keys = np.arange(len(schur.cams))
    T_w_c = inverse(p.T_c_w[schur.cams])
    values = gtsam.Values()
    rng = np.random.default_rng(10)
    insert_poses(values, keys, np.array([T @ gtsam.Pose3.Expmap(rng.normal(0.0, 1e-3, 6)).matrix() for T in T_w_c]))
    split = schur.factors(keys, T_w_c, groups)
    assert len(split) == 2
    whole = schur.factor(keys, T_w_c).error(values)
    assert abs(sum(f.error(values) for f in split) - whole) < 1e-9 * whole
