"""The static local BA's numpy Levenberg-Marquardt (optim/schur_lm.py) against gtsam's on the same window."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynaslam2.config import OptimConfig, load_config
from dynaslam2.errors import ConfigError
from dynaslam2.geometry.se3 import inverse
from dynaslam2.optim import BAProblem, local_bundle_adjustment
from dynaslam2.optim.synthetic import kitti_like_camera, make_window

CAMERA = kitti_like_camera()


def window_problem(seed: int, n_fixed: int = 3, mono_fraction: float = 0.2) -> BAProblem:
    """10 keyframes 1 m apart, 1000 points over 5 views, 5 % gross outliers, a fifth monocular."""
    rng = np.random.default_rng(seed)
    w = make_window(rng, CAMERA, n_keyframes=10, n_fixed=n_fixed, n_points=1000, track_length=5,
                    outlier_fraction=0.05, pose_sigma=(0.05, 0.005))
    meas = w.obs.meas.copy()
    meas[rng.random(len(meas)) < mono_fraction, 2] = -1.0
    return BAProblem(w.T_c_w_init, w.fixed, w.X_w_init, w.obs_kf, w.obs_pt, meas, w.obs.inv_sigma2)


@pytest.mark.parametrize("robust, refine, lam, n_fixed", [(1, 0, 1e-4, 3), (5, 0, 1e-4, 3), (2, 3, 1.0, 3),
                                                          (3, 0, 1e-4, 0)])
def test_steps_are_gtsams(robust, refine, lam, n_fixed):
    """Same window, same stages and LM settings: the numpy solver takes gtsam's steps (poses within 1e-9 m,
    points within 1e-6 m after up to 5 iterations), with the same iteration count, cost and inliers; with
    no fixed keyframe both hold the first one."""
    problem = window_problem(5, n_fixed)
    results = [local_bundle_adjustment(problem, CAMERA, OptimConfig(
        local_ba_iterations_robust=robust, local_ba_iterations_refine=refine, local_ba_lambda_initial=lam,
        local_ba_solver=solver)) for solver in ("schur", "gtsam")]
    schur, gtsam_ = results
    assert schur.iterations == gtsam_.iterations > 0
    assert np.abs(inverse(schur.T_c_w)[:, :3, 3] - inverse(gtsam_.T_c_w)[:, :3, 3]).max() < 1e-9
    assert np.abs(schur.X_w - gtsam_.X_w).max() < 1e-6
    assert np.array_equal(schur.inlier, gtsam_.inlier)
    assert np.isclose(schur.final_error, gtsam_.final_error, rtol=1e-9)
    assert schur.final_error < schur.initial_error
    fixed = problem.fixed if n_fixed else np.arange(len(problem.fixed)) == 0
    assert np.array_equal(schur.T_c_w[fixed], problem.T_c_w[fixed])


def test_diagonal_damping_needs_the_gtsam_solver():
    with pytest.raises(ConfigError, match="local_ba_solver=gtsam"):
        load_config(None, ["optim.diagonal_damping=true"])
    assert load_config(None, ["optim.diagonal_damping=true", "optim.local_ba_solver=gtsam"]).optim.diagonal_damping


def test_window_without_free_camera_moves_only_the_points():
    """Every keyframe fixed: the numpy solver has no camera system; the points still take their steps."""
    problem = dataclasses.replace(window_problem(6), fixed=np.ones(10, dtype=bool))
    schur, gtsam_ = (local_bundle_adjustment(problem, CAMERA, OptimConfig(local_ba_solver=s)) for s in ("schur", "gtsam"))
    assert np.array_equal(schur.T_c_w, problem.T_c_w)
    assert np.abs(schur.X_w - gtsam_.X_w).max() < 1e-6 and schur.final_error < schur.initial_error
