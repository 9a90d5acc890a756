"""Pose-only optimization with Huber kernels and chi-square outlier rounds (ORB-SLAM2's PoseOptimization).

The points are constants, so the problem has one 6-dof variable. gtsam has no built-in pose-only
stereo factor; the alternatives built from built-in factors (points as variables held by strong
priors or NonlinearEquality) make gtsam eliminate one clique per point, measured ~35 ms per
10 LM iterations at N=1000 (benchmarks/bench_ba.py, `--pose-variant builtin`). So all correspondences
go into ONE `gtsam.CustomFactor` whose residuals and Jacobians are vectorized numpy: gtsam's
Levenberg-Marquardt drives the 6-dof solve.
"""

from __future__ import annotations

import gtsam
import numpy as np

from dynaslam2.config import OptimConfig
from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import hat
from dynaslam2.optim.gtsam_utils import lm_params, matrix_from_pose3, pose3_from_matrix
from dynaslam2.optim.reprojection import chi2, chi2_thresholds, huber_cost, is_stereo, jacobian_point, residuals


def optimize_pose(
    T_c_w_init: np.ndarray,
    X_w: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    camera: StereoCamera,
    cfg: OptimConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Refine `T_c_w` from 3D-2D correspondences; returns (T_c_w (4,4), inliers (N,) bool).

    Each of `cfg.pose_rounds` rounds restarts from `T_c_w_init`, runs `cfg.pose_iterations` LM steps on
    the current inliers, then re-tests every correspondence: chi2 > 7.815 (stereo) / 5.991 (mono) or a
    point behind the camera is an outlier. Huber (delta = sqrt of the threshold) in the first
    `cfg.pose_robust_rounds` rounds. Fewer than `cfg.pose_min_points` correspondences: init, all False.
    """
    T_c_w_init, X_w, meas, inv_sigma2 = _check_inputs(T_c_w_init, X_w, meas, inv_sigma2)
    n = len(X_w)
    if n < cfg.pose_min_points:
        return T_c_w_init.copy(), np.zeros(n, dtype=bool)
    th = chi2_thresholds(meas, cfg.chi2_mono, cfg.chi2_stereo)
    inliers = np.ones(n, dtype=bool)
    T_c_w = T_c_w_init.copy()
    for rnd in range(cfg.pose_rounds):
        if inliers.sum() < cfg.pose_min_points:
            break
        robust = rnd < cfg.pose_robust_rounds
        T_c_w = _solve(T_c_w_init, X_w[inliers], meas[inliers], inv_sigma2[inliers], th[inliers] if robust else None,
                       camera, cfg)
        X_c = X_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
        inliers = (chi2(residuals(camera, X_c, meas), inv_sigma2) <= th) & (X_c[:, 2] > cfg.min_depth)
        if inliers.sum() < cfg.pose_min_inliers:
            break
    return T_c_w, inliers


def _solve(
    T_c_w: np.ndarray,
    X_w: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    huber_delta2: np.ndarray | None,
    camera: StereoCamera,
    cfg: OptimConfig,
) -> np.ndarray:
    """LM from `T_c_w` on the single pose variable (gtsam key 0)."""
    graph = gtsam.NonlinearFactorGraph()
    graph.push_back(pose_only_factor(0, X_w, meas, inv_sigma2, huber_delta2, camera, cfg.min_depth))
    values = gtsam.Values()
    values.insert(0, pose3_from_matrix(T_c_w))
    params = lm_params(cfg, cfg.pose_iterations)
    return matrix_from_pose3(gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize().atPose3(0))


def pose_only_factor(
    key: int,
    X: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    huber_delta2: np.ndarray | None,
    camera: StereoCamera,
    min_depth: float,
) -> gtsam.CustomFactor:
    """One factor on the Pose3 `T_c_x` at `key` (x: the frame of the constant points `X`, world or an
    object) holding all reprojection residuals, whitened by sqrt(inv_sigma2) (paper eq. (1)).

    Tangent order (omega, v), perturbation on the right: X_c = R Exp(omega) X + R v + t, so
    dX_c/domega = -R [X]x and dX_c/dv = R. With `huber_delta2` (per-observation delta^2), the
    linearization is reweighted as gtsam's Robust noise model does (sqrt of the Huber weight), and
    the error evaluation returns residuals whose half squared norm is the Huber cost. Points closer
    than `min_depth` contribute nothing.
    """
    stereo = is_stereo(meas)
    keep = np.ones((len(meas), 3), dtype=bool)
    keep[~stereo, 2] = False
    keep = keep.ravel()
    sqrt_info = np.sqrt(inv_sigma2)

    def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        T = matrix_from_pose3(values.atPose3(key))
        R = T[:3, :3]
        X_c = X @ R.T + T[:3, 3]
        w = sqrt_info * (X_c[:, 2] > min_depth)
        r = residuals(camera, X_c, meas) * w[:, None]
        if huber_delta2 is not None:
            c2 = np.maximum(np.einsum("ij,ij->i", r, r), 1e-300)
            if H is None:
                scale = np.sqrt(2.0 * huber_cost(c2, huber_delta2) / c2)
            else:
                scale = np.sqrt(np.minimum(1.0, np.sqrt(huber_delta2 / c2)))
            r = r * scale[:, None]
            w = w * scale
        if H is not None:
            dX_c = np.concatenate([-R @ hat(X), np.broadcast_to(R, (len(X), 3, 3))], -1)
            J = np.einsum("mij,mjk->mik", jacobian_point(camera, X_c, meas), dX_c) * w[:, None, None]
            H[0] = J.reshape(-1, 6)[keep]
        return r.ravel()[keep]

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(int(keep.sum())), [key], error)


def _check_inputs(
    T_c_w: np.ndarray, X_w: np.ndarray, meas: np.ndarray, inv_sigma2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    T_c_w = np.asarray(T_c_w, dtype=float)
    X_w = np.asarray(X_w, dtype=float).reshape(-1, 3)
    meas = np.asarray(meas, dtype=float).reshape(-1, 3)
    inv_sigma2 = np.asarray(inv_sigma2, dtype=float).reshape(-1)
    if T_c_w.shape != (4, 4) or not np.all(np.isfinite(T_c_w)):
        raise InputError(f"optimize_pose: T_c_w_init must be a finite (4, 4) matrix, got shape {T_c_w.shape}")
    if not len(X_w) == len(meas) == len(inv_sigma2):
        raise InputError(f"optimize_pose: X_w, meas, inv_sigma2 must have the same length, got "
                         f"{len(X_w)}, {len(meas)}, {len(inv_sigma2)}")
    if not (np.all(np.isfinite(X_w)) and np.all(np.isfinite(meas)) and np.all(inv_sigma2 > 0)):
        raise InputError("optimize_pose: X_w and meas must be finite and inv_sigma2 positive")
    return T_c_w, X_w, meas, inv_sigma2
