"""Local bundle adjustment over a covisible window, the rest fixed (ORB-SLAM2's LocalBundleAdjustment).

The problem is plain arrays (`BAProblem`); gtsam stays inside. Keyframe `k` is the gtsam Pose3
`T_w_c` at key `pose_keys[k]`, point `j` the Point3 `X_w` at `point_keys[j]` (`allocate_keys`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from dynaslam2.config import OptimConfig
from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse
from dynaslam2.optim.gtsam_utils import (
    add_stereo_projection_factors,
    allocate_keys,
    extract_points,
    extract_poses,
    insert_points,
    insert_poses,
    lm_params,
)
from dynaslam2.optim.reprojection import chi2, chi2_thresholds, huber_cost, is_stereo, residuals

FIXED_POSE_SIGMA = 1e-9  # prior sigma holding a fixed keyframe (its returned pose is the input, exactly)


@dataclass
class BAProblem:
    """A local BA window. `meas` rows are `[u, v, u_right]`, `u_right < 0` for monocular observations."""

    T_c_w: np.ndarray  # (K, 4, 4) keyframe poses
    fixed: np.ndarray  # (K,) bool: fixed keyframes (covisible but outside the local window)
    X_w: np.ndarray  # (P, 3) map points
    obs_kf: np.ndarray  # (M,) int index into keyframes
    obs_pt: np.ndarray  # (M,) int index into points
    meas: np.ndarray  # (M, 3)
    inv_sigma2: np.ndarray  # (M,) 1/sigma^2 of the keypoint's pyramid level


@dataclass
class BAResult:
    """Optimized window. `inlier`: the observation passes the chi2 / positive-depth test at the end.

    `initial_error` / `final_error`: summed Huber cost of all observations (whitened, chi2 deltas)
    at the input and at the output.
    """

    T_c_w: np.ndarray
    X_w: np.ndarray
    inlier: np.ndarray
    iterations: int
    initial_error: float
    final_error: float
    timings_ms: dict[str, float] = field(default_factory=dict)  # "build" (graph, values, ordering), "solve" (LM)


def local_bundle_adjustment(problem: BAProblem, camera: StereoCamera, cfg: OptimConfig) -> BAResult:
    """`cfg.ba_iterations_robust` LM iterations with Huber, drop observations with chi2 > 7.815 (stereo) /
    5.991 (mono) or behind the camera, then `cfg.ba_iterations_refine` iterations without kernel.

    Fixed keyframes stay exactly as given; with none fixed, the first keyframe fixes the gauge.
    Points that the kept observations cannot determine (a single monocular observation) are left
    unchanged.
    """
    _check(problem)
    fixed = problem.fixed.astype(bool).copy()
    if not fixed.any():
        fixed[0] = True
    th = chi2_thresholds(problem.meas, cfg.chi2_mono, cfg.chi2_stereo)
    T_c_w = problem.T_c_w.astype(float).copy()
    X_w = problem.X_w.astype(float).copy()
    initial_chi2, initial_depth = _chi2_depth(problem, T_c_w, X_w, camera)
    use = np.ones(len(problem.obs_kf), dtype=bool)
    iterations = 0
    timings_ms = {"build": 0.0, "solve": 0.0}
    for robust, n_iter in ((True, cfg.ba_iterations_robust), (False, cfg.ba_iterations_refine)):
        if not robust:
            c2, depth = _chi2_depth(problem, T_c_w, X_w, camera)
            use = (c2 <= th) & (depth > cfg.min_depth)
        if n_iter == 0 or not use.any():
            continue
        T_c_w, X_w, n = _optimize(problem, use, fixed, T_c_w, X_w, robust, n_iter, camera, cfg, timings_ms)
        iterations += n
    final_chi2, final_depth = _chi2_depth(problem, T_c_w, X_w, camera)
    T_c_w[fixed] = problem.T_c_w[fixed]
    return BAResult(
        T_c_w=T_c_w,
        X_w=X_w,
        inlier=(final_chi2 <= th) & (final_depth > cfg.min_depth),
        iterations=iterations,
        initial_error=float(huber_cost(initial_chi2, th).sum()),
        final_error=float(huber_cost(final_chi2, th).sum()),
        timings_ms=timings_ms,
    )


def _optimize(
    problem: BAProblem,
    use: np.ndarray,
    fixed: np.ndarray,
    T_c_w: np.ndarray,
    X_w: np.ndarray,
    robust: bool,
    n_iter: int,
    camera: StereoCamera,
    cfg: OptimConfig,
    timings_ms: dict[str, float],
) -> tuple[np.ndarray, np.ndarray, int]:
    """One LM run on the observations `use` (Huber if `robust`); returns the updated (T_c_w, X_w, iterations)
    and adds its build / solve milliseconds to `timings_ms`."""
    t_start = time.perf_counter()
    obs_kf, obs_pt = problem.obs_kf[use], problem.obs_pt[use]
    meas = problem.meas[use]
    n_obs = np.bincount(obs_pt, minlength=len(X_w))
    n_stereo = np.bincount(obs_pt, weights=is_stereo(meas), minlength=len(X_w))
    determined = (n_obs >= 2) | (n_stereo >= 1)
    keep = determined[obs_pt]
    obs_kf, obs_pt, meas = obs_kf[keep], obs_pt[keep], meas[keep]
    kf_used = np.zeros(len(T_c_w), dtype=bool)
    kf_used[obs_kf] = True
    kf_idx = np.flatnonzero(kf_used)
    pt_idx = np.flatnonzero(determined)
    pose_keys, point_keys = allocate_keys(len(kf_idx), len(pt_idx))
    kf_key = np.full(len(T_c_w), -1, dtype=np.int64)
    kf_key[kf_idx] = pose_keys
    pt_key = np.full(len(X_w), -1, dtype=np.int64)
    pt_key[pt_idx] = point_keys

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    T_w_c = inverse(T_c_w[kf_idx])
    insert_poses(values, pose_keys, T_w_c)
    insert_points(values, point_keys, X_w[pt_idx])
    prior = gtsam.noiseModel.Isotropic.Sigma(6, FIXED_POSE_SIGMA)
    for key, T in zip(pose_keys[fixed[kf_idx]].tolist(), T_w_c[fixed[kf_idx]]):
        graph.addPriorPose3(key, gtsam.Pose3(T), prior)
    if not fixed[kf_idx].any():  # the window's only fixed keyframes lost all their kept observations
        graph.addPriorPose3(int(pose_keys[0]), gtsam.Pose3(T_w_c[0]), prior)
    add_stereo_projection_factors(graph, kf_key[obs_kf], pt_key[obs_pt], meas, problem.inv_sigma2[use][keep], camera,
                                  np.sqrt(cfg.chi2_mono) if robust else None,
                                  np.sqrt(cfg.chi2_stereo) if robust else None)
    params = lm_params(cfg, n_iter, np.concatenate([point_keys, pose_keys]))
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    t_built = time.perf_counter()
    result = optimizer.optimize()
    timings_ms["build"] += 1e3 * (t_built - t_start)
    timings_ms["solve"] += 1e3 * (time.perf_counter() - t_built)
    T_c_w = T_c_w.copy()
    X_w = X_w.copy()
    T_c_w[kf_idx] = inverse(extract_poses(result))
    X_w[pt_idx] = extract_points(result)
    return T_c_w, X_w, optimizer.iterations()


def _chi2_depth(
    problem: BAProblem, T_c_w: np.ndarray, X_w: np.ndarray, camera: StereoCamera
) -> tuple[np.ndarray, np.ndarray]:
    """(M,) chi2 and depth of every observation at the given estimate."""
    R = T_c_w[problem.obs_kf, :3, :3]
    X_c = np.einsum("mij,mj->mi", R, X_w[problem.obs_pt]) + T_c_w[problem.obs_kf, :3, 3]
    return chi2(residuals(camera, X_c, problem.meas), problem.inv_sigma2), X_c[:, 2]


def _check(problem: BAProblem) -> None:
    K, P, M = len(problem.T_c_w), len(problem.X_w), len(problem.obs_kf)
    shapes_ok = (
        problem.T_c_w.shape == (K, 4, 4)
        and problem.fixed.shape == (K,)
        and problem.X_w.shape == (P, 3)
        and problem.obs_pt.shape == (M,)
        and problem.meas.shape == (M, 3)
        and problem.inv_sigma2.shape == (M,)
    )
    if not shapes_ok or K == 0:
        raise InputError("local_bundle_adjustment: expected T_c_w (K,4,4), fixed (K,), X_w (P,3), obs_kf/obs_pt "
                         "(M,), meas (M,3), inv_sigma2 (M,) with K >= 1")
    if M and (problem.obs_kf.min() < 0 or problem.obs_kf.max() >= K or problem.obs_pt.min() < 0
              or problem.obs_pt.max() >= P):
        raise InputError(f"local_bundle_adjustment: obs_kf must index [0, {K}) and obs_pt [0, {P})")
    if not (np.all(np.isfinite(problem.T_c_w)) and np.all(np.isfinite(problem.X_w))
            and np.all(np.isfinite(problem.meas)) and np.all(problem.inv_sigma2 > 0)):
        raise InputError("local_bundle_adjustment: poses, points and measurements must be finite, inv_sigma2 > 0")
