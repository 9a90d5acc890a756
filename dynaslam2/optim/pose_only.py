"""Pose-only optimization with Huber kernels and chi-square outlier rounds (ORB-SLAM2's PoseOptimization).

The points are constants, so the problem has one 6-dof variable. gtsam has no built-in pose-only
stereo factor; built from built-in factors only (points as Point3 variables held by strong priors,
`python benchmarks/bench_ba.py --pose-builtin`), gtsam eliminates one clique per point: measured
70 / 212 ms CPU for N = 300 / 1000, against 8 / 11 ms for ONE `gtsam.CustomFactor` holding all
correspondences with closed-form vectorized numpy residuals and Jacobians (same rounds, same
thresholds). gtsam's Levenberg-Marquardt drives the 6-dof solve."""

from __future__ import annotations

import gtsam
import numpy as np

from dynaslam2.config import OptimConfig
from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse
from dynaslam2.optim.gtsam_utils import lm_params, matrix_from_pose3, pose3_from_matrix
from dynaslam2.optim.reprojection import chi2, chi2_thresholds, disparity_residuals, huber_cost, is_stereo, residuals


def optimize_pose(
    T_c_w_init: np.ndarray,
    X_w: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    camera: StereoCamera,
    cfg: OptimConfig,
    disparity_weight: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Refine `T_c_w` from 3D-2D correspondences; returns (T_c_w (4,4), inliers (N,) bool).

    Each of `cfg.pose_rounds` rounds runs `cfg.pose_iterations` LM steps on the current inliers, from
    the previous round's pose (from `T_c_w_init` with `cfg.pose_restart_rounds`, as ORB-SLAM2: same
    result on the benchmark, twice the time), then re-tests every correspondence: chi2 > 7.815
    (stereo) / 5.991 (mono) or a point behind the camera is an outlier. Huber (delta = sqrt of the
    threshold) in the first `cfg.pose_robust_rounds` rounds. Fewer than `cfg.pose_min_points`
    correspondences: init, all False. `disparity_weight` (N,): stereo residuals are `[u, v, disparity]`,
    the disparity at sigma / disparity_weight (`pose_only_factor`), in the solve and in the test.
    """
    T_c_w_init, X_w, meas, inv_sigma2 = _check_inputs(T_c_w_init, X_w, meas, inv_sigma2)
    n = len(X_w)
    if disparity_weight is not None:
        disparity_weight = np.broadcast_to(np.asarray(disparity_weight, dtype=np.float64), (n,))
    if n < cfg.pose_min_points:
        return T_c_w_init.copy(), np.zeros(n, dtype=bool)
    th = chi2_thresholds(meas, cfg.chi2_mono, cfg.chi2_stereo)
    inliers = np.ones(n, dtype=bool)
    T_c_w = T_c_w_init.copy()
    for rnd in range(cfg.pose_rounds):
        if inliers.sum() < cfg.pose_min_points:
            break
        robust = rnd < cfg.pose_robust_rounds
        start = T_c_w_init if cfg.pose_restart_rounds else T_c_w
        T_c_w = _solve(start, X_w[inliers], meas[inliers], inv_sigma2[inliers], th[inliers] if robust else None, camera,
                       cfg, None if disparity_weight is None else disparity_weight[inliers])
        X_c = X_w @ T_c_w[:3, :3].T + T_c_w[:3, 3]
        e = residuals(camera, X_c, meas)
        if disparity_weight is not None:
            e = disparity_residuals(e, meas, disparity_weight)
        inliers = (chi2(e, inv_sigma2) <= th) & (X_c[:, 2] > cfg.min_depth)
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
    disparity_weight: np.ndarray | None,
) -> np.ndarray:
    """LM from `T_c_w` on the single pose variable (gtsam key 0 holds T_w_c)."""
    graph = gtsam.NonlinearFactorGraph()
    graph.push_back(pose_only_factor(0, X_w, meas, inv_sigma2, huber_delta2, camera, cfg.min_depth, disparity_weight))
    values = gtsam.Values()
    values.insert(0, pose3_from_matrix(inverse(T_c_w)))
    params = lm_params(cfg, cfg.pose_iterations, cfg.pose_relative_error_tol)
    T_w_c = matrix_from_pose3(gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize().atPose3(0))
    return inverse(T_w_c)


def pose_only_factor(
    key: int,
    X: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    huber_delta2: np.ndarray | None,
    camera: StereoCamera,
    min_depth: float,
    disparity_weight: np.ndarray | float | None = None,
) -> gtsam.CustomFactor:
    """One factor on the camera pose Pose3 `T_x_c` at `key` (x: the frame of the constant points `X`,
    the world or an object) holding all reprojection residuals whitened by sqrt(inv_sigma2) (eq. (1)).

    gtsam perturbs on the right, T_x_c Exp(omega, v), so the camera-frame point moves by
    X_c' = X_c + [X_c]x omega - v: the 3x6 Jacobian per observation is [J_pt [X_c]x, -J_pt] with
    J_pt = d pi / d X_c, closed-form and vectorized. With `huber_delta2` (per-observation delta^2),
    the linearization is reweighted as gtsam's Robust noise model does (sqrt of the Huber weight) and
    the error evaluation returns residuals whose half squared norm is the Huber cost. Points closer
    than `min_depth` contribute nothing.

    `disparity_weight` (per observation or one): the third residual of a stereo observation is the
    disparity, predicted bf / z minus measured u - u_right, at sigma / disparity_weight, instead of
    u_right at sigma (ORB-SLAM2's isotropic `[u, v, u_right]`, which gives the disparity a sigma of
    sqrt(2) x the keypoint's: ~1.4 px, where the sub-pixel SAD measures it to ~0.1 px).
    """
    n = len(meas)
    stereo = is_stereo(meas)
    rows = np.flatnonzero(np.column_stack([np.ones((n, 2), bool), stereo]).ravel())
    sqrt_info = np.sqrt(inv_sigma2)
    fx, fy, cx, cy, bf = camera.fx, camera.fy, camera.cx, camera.cy, camera.bf

    def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        T_x_c = matrix_from_pose3(values.atPose3(key))
        x, y, z = ((X - T_x_c[:3, 3]) @ T_x_c[:3, :3]).T
        w = np.where(z > min_depth, sqrt_info, 0.0)
        inv_z = 1.0 / np.where(z > min_depth, z, 1.0)
        u = fx * x * inv_z + cx
        r = np.empty((n, 3))
        r[:, 0] = u - meas[:, 0]
        r[:, 1] = fy * y * inv_z + cy - meas[:, 1]
        if disparity_weight is None:
            r[:, 2] = np.where(stereo, u - bf * inv_z - meas[:, 2], 0.0)
        else:
            r[:, 2] = np.where(stereo, disparity_weight * (bf * inv_z - meas[:, 0] + meas[:, 2]), 0.0)
        r *= w[:, None]
        if huber_delta2 is not None:
            c2 = np.maximum(np.einsum("ij,ij->i", r, r), 1e-300)
            if H is None:
                scale = np.sqrt(2.0 * huber_cost(c2, huber_delta2) / c2)
            else:
                scale = np.sqrt(np.minimum(1.0, np.sqrt(huber_delta2 / c2)))
            r *= scale[:, None]
            w = w * scale
        if H is not None:
            # rows of d pi / d X_c: (a, 0, c), (0, b, d), (a3, 0, e); the 3x6 block is [row x X_c, -row]
            # (disparity: a3 = 0, e = -k bf / z^2)
            a = w * fx * inv_z
            b = w * fy * inv_z
            c = -a * x * inv_z
            d = -b * y * inv_z
            if disparity_weight is None:
                a3, e = a, -w * (fx * x - bf) * inv_z**2
            else:
                a3, e = np.zeros(n), -w * disparity_weight * bf * inv_z**2
            J = np.zeros((n, 3, 6))
            J[:, 0, 0], J[:, 0, 1], J[:, 0, 2] = -c * y, c * x - a * z, a * y
            J[:, 0, 3], J[:, 0, 5] = -a, -c
            J[:, 1, 0], J[:, 1, 1], J[:, 1, 2] = b * z - d * y, d * x, -b * x
            J[:, 1, 4], J[:, 1, 5] = -b, -d
            J[:, 2, 0], J[:, 2, 1], J[:, 2, 2] = -e * y, e * x - a3 * z, a3 * y
            J[:, 2, 3], J[:, 2, 5] = -a3, -e
            H[0] = J.reshape(-1, 6)[rows]
        return r.ravel()[rows]

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(rows)), [key], error)


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
