"""Local bundle adjustment over a covisible window, the rest fixed (ORB-SLAM2's LocalBundleAdjustment).

The problem is plain arrays (`BAProblem`). The LM stages run in numpy (`optim.local_ba_solver`
"schur", the default: optim/schur_lm.py, the points eliminated in closed form) or in gtsam ("gtsam", the
reference: the same steps to 1e-9 m, tests/test_schur_lm.py). With gtsam, keyframe `k` is the Pose3
`T_w_c` at key `pose_keys[k]`, point `j` the Point3 `X_w` at `point_keys[j]` (`allocate_keys`).

Cost of the gtsam solver (SLAM windows of sim static 640x480: ~3300 points, ~14.7k observations; 2 loaded
cores): one LM iteration is gtsam's sequential Cholesky elimination (~50-70 ms, points first), linearization
(~15-20 ms) and two error evaluations; with the default single robust iteration (`OptimConfig.local_ba_*`)
building the graph (`add_stereo_factors`, stereo factors made in a Python loop, ~3.3 us each) is ~1/4 and
the Values ~5%: the numpy solver does the same iteration without a graph (schur_lm.py for the figures).
Measured and dropped for gtsam: numpy Schur complement on gtsam's linearization (`sparseJacobian_`
alone costs as much as `linearize`: <= 1.4x per iteration for much code), C++-built projection pairs
for the robust stage too (1.03x: cheaper build, costlier elimination), gtsam's SfmLevenbergMarquardtOptimizer
(Full and Schur modes, 1.1-2.5x slower), smart factors (SmartProjectionRigFactor with per-level scaled
calibrations: linearizing 2800 of them costs more than eliminating the points; no Huber), Dogleg (cheaper
steps, ~30% higher cost after 5), Gauss-Newton (the first step already raises the cost), leaving single
stereo-observation points out of the graph (no measurable gain)."""

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
    add_stereo_factors,
    StereoFactorCache,
    add_stereo_projection_factors,
    allocate_keys,
    extract_points,
    extract_poses,
    insert_points,
    insert_poses,
    lm_params,
)
from dynaslam2.optim.reprojection import chi2_depth, chi2_thresholds, huber_cost, is_stereo
from dynaslam2.optim.schur_lm import schur_levenberg_marquardt

FIXED_POSE_SIGMA = 1e-9  # prior sigma holding a fixed keyframe (its returned pose is the input, exactly)
POINT_KEY_BASE = 2**31  # with stable ids, keyframe id k is gtsam key k and point id j key POINT_KEY_BASE + j


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
    # Optional stable ids (strictly increasing, in [0, 2^31)): the gtsam keys (points after POINT_KEY_BASE),
    # so that a `StereoFactorCache` can reuse the factors of observations seen by the previous window.
    # (keyword-only: subclasses such as object_ba.ObjectBAProblem add required fields after these)
    kf_ids: np.ndarray | None = field(default=None, kw_only=True)  # (K,)
    pt_ids: np.ndarray | None = field(default=None, kw_only=True)  # (P,)


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


def local_bundle_adjustment(problem: BAProblem, camera: StereoCamera, cfg: OptimConfig,
                            cache: StereoFactorCache | None = None) -> BAResult:
    """`cfg.local_ba_iterations_robust` LM iterations with Huber, drop observations with chi2 > 7.815 (stereo) /
    5.991 (mono) or behind the camera, then `cfg.local_ba_iterations_refine` iterations without kernel.

    Fixed keyframes stay exactly as given (held by strong priors: measured ~2x faster than
    NonlinearEquality, which makes gtsam eliminate with QR); with none fixed, the first keyframe fixes
    the gauge. Points that the kept observations cannot determine (a single monocular observation)
    are left unchanged. `cfg.local_ba_solver` runs the LM stages in numpy (optim/schur_lm.py, the default)
    or in gtsam; with gtsam, `cache` (needs the problem's stable ids) reuses the robust stage's stereo
    factors of observations that the previous call also had.
    """
    _check(problem)
    if cache is not None and problem.kf_ids is None:
        raise InputError("local_bundle_adjustment: a factor cache needs the problem's kf_ids and pt_ids")
    t_start = time.perf_counter()
    fixed = problem.fixed.astype(bool).copy()
    if not fixed.any():
        fixed[0] = True
    th = chi2_thresholds(problem.meas, cfg.chi2_mono, cfg.chi2_stereo)
    T_c_w = problem.T_c_w.astype(float).copy()
    X_w = problem.X_w.astype(float).copy()
    initial_chi2, _ = static_chi2_depth(problem, T_c_w, X_w, camera)
    stereo = is_stereo(problem.meas)

    use = determined_observations(problem, np.ones(len(problem.obs_kf), dtype=bool), stereo)
    stages = _SchurStages(problem, fixed, camera, cfg) if cfg.local_ba_solver == "schur" else \
        _GtsamStages(problem, fixed, use, T_c_w, X_w, camera, cfg, cache)
    iterations = 0
    timings_ms = {"build": 1e3 * (time.perf_counter() - t_start), "solve": 0.0}
    for robust, n_iter in ((True, cfg.local_ba_iterations_robust), (False, cfg.local_ba_iterations_refine)):
        if not robust and n_iter == 0:
            break  # no refine stage: the final classification below is ORB-SLAM2's outlier removal
        if not robust:
            c2, depth = static_chi2_depth(problem, T_c_w, X_w, camera)
            use = determined_observations(problem, (c2 <= th) & (depth > cfg.min_depth), stereo)
        if n_iter == 0 or not use.any():
            continue
        T_c_w, X_w, n = stages.run(use, robust, n_iter, th, T_c_w, X_w, timings_ms)
        iterations += n

    final_chi2, final_depth = static_chi2_depth(problem, T_c_w, X_w, camera)
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


class _SchurStages:
    """The LM stages in numpy (optim/schur_lm.py): every stage starts from the current arrays."""

    def __init__(self, problem: BAProblem, fixed: np.ndarray, camera: StereoCamera, cfg: OptimConfig) -> None:
        self.problem, self.fixed, self.camera, self.cfg = problem, fixed, camera, cfg

    def run(self, use: np.ndarray, robust: bool, n_iter: int, th: np.ndarray, T_c_w: np.ndarray, X_w: np.ndarray,
            timings_ms: dict[str, float]) -> tuple[np.ndarray, np.ndarray, int]:
        p, cfg = self.problem, self.cfg
        t0 = time.perf_counter()
        # the gauge as the gtsam stages: the fixed keyframes with observations, else the first observed one
        observed = np.bincount(p.obs_kf[use], minlength=len(T_c_w)) > 0
        free = observed & ~self.fixed
        if not (observed & self.fixed).any():
            free[np.flatnonzero(observed)[0]] = False
        T_c_w, X_w, n = schur_levenberg_marquardt(
            T_c_w, free, X_w, p.obs_kf[use], p.obs_pt[use], p.meas[use], p.inv_sigma2[use], self.camera,
            cfg.min_depth, th[use] if robust else None, n_iter, cfg.local_ba_lambda_initial,
            cfg.ba_relative_error_tol, cfg.lambda_fixed_factor)
        timings_ms["solve"] += 1e3 * (time.perf_counter() - t0)
        return T_c_w, X_w, n


class _GtsamStages:
    """The LM stages in gtsam: keys for the keyframes and determined points of the whole window, kept
    through both stages (the refine stage erases those its observations no longer determine)."""

    def __init__(self, problem: BAProblem, fixed: np.ndarray, use: np.ndarray, T_c_w: np.ndarray, X_w: np.ndarray,
                 camera: StereoCamera, cfg: OptimConfig, cache: StereoFactorCache | None) -> None:
        self.problem, self.camera, self.cfg, self.cache = problem, camera, cfg, cache
        self.kf_idx = np.flatnonzero(np.bincount(problem.obs_kf[use], minlength=len(T_c_w)) > 0)
        self.pt_idx = np.flatnonzero(np.bincount(problem.obs_pt[use], minlength=len(X_w)) > 0)
        if problem.kf_ids is None:
            pose_keys, point_keys = allocate_keys(len(self.kf_idx), len(self.pt_idx))
        else:  # increasing ids: key order is index order, as extract_poses / extract_points return them
            pose_keys = np.asarray(problem.kf_ids, dtype=np.int64)[self.kf_idx]
            point_keys = POINT_KEY_BASE + np.asarray(problem.pt_ids, dtype=np.int64)[self.pt_idx]
        self.kf_key = np.full(len(T_c_w), -1, dtype=np.int64)
        self.kf_key[self.kf_idx] = pose_keys
        self.pt_key = np.full(len(X_w), -1, dtype=np.int64)
        self.pt_key[self.pt_idx] = point_keys
        self.values = gtsam.Values()
        insert_poses(self.values, pose_keys, inverse(T_c_w[self.kf_idx]))
        insert_points(self.values, point_keys, X_w[self.pt_idx])
        self.fixed_keys = pose_keys[fixed[self.kf_idx]] if fixed[self.kf_idx].any() else pose_keys[:1]

    def run(self, use: np.ndarray, robust: bool, n_iter: int, th: np.ndarray, T_c_w: np.ndarray, X_w: np.ndarray,
            timings_ms: dict[str, float]) -> tuple[np.ndarray, np.ndarray, int]:
        p, cfg, kf_key, pt_key = self.problem, self.cfg, self.kf_key, self.pt_key
        t_build = time.perf_counter()
        if not robust:
            # points no longer determined and free keyframes left without observations keep their estimate
            dropped_pt = np.setdiff1d(self.pt_idx, p.obs_pt[use])
            still_used = np.concatenate([p.obs_kf[use], self.kf_idx[np.isin(kf_key[self.kf_idx], self.fixed_keys)]])
            dropped_kf = np.setdiff1d(self.kf_idx, still_used)
            for key in np.concatenate([pt_key[dropped_pt], kf_key[dropped_kf]]).tolist():
                self.values.erase(key)
            self.pt_idx = np.setdiff1d(self.pt_idx, dropped_pt)
            self.kf_idx = np.setdiff1d(self.kf_idx, dropped_kf)
        graph = gtsam.NonlinearFactorGraph()
        prior = gtsam.noiseModel.Isotropic.Sigma(6, FIXED_POSE_SIGMA)
        for key in self.fixed_keys.tolist():
            graph.addPriorPose3(key, self.values.atPose3(key), prior)
        # Huber on the whole 3-dof stereo residual (Python-built stereo factors); without kernel the
        # C++-built projection pairs have exactly the same cost at ~1/6 of the build time.
        args = (graph, kf_key[p.obs_kf[use]], pt_key[p.obs_pt[use]], p.meas[use], p.inv_sigma2[use], self.camera)
        if robust:
            add_stereo_factors(*args, np.sqrt(cfg.chi2_mono), np.sqrt(cfg.chi2_stereo), self.cache)
        else:
            add_stereo_projection_factors(*args, None, None)
        params = lm_params(cfg, n_iter, cfg.ba_relative_error_tol,
                           np.concatenate([pt_key[self.pt_idx], kf_key[self.kf_idx]]), cfg.local_ba_lambda_initial)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, self.values, params)
        t_solve = time.perf_counter()
        self.values = optimizer.optimize()
        timings_ms["build"] += 1e3 * (t_solve - t_build)
        timings_ms["solve"] += 1e3 * (time.perf_counter() - t_solve)
        T_c_w, X_w = T_c_w.copy(), X_w.copy()
        T_c_w[self.kf_idx] = inverse(extract_poses(self.values))
        X_w[self.pt_idx] = extract_points(self.values)
        return T_c_w, X_w, optimizer.iterations()


def determined_observations(problem: BAProblem, use: np.ndarray, stereo: np.ndarray) -> np.ndarray:
    """`use` restricted to observations of points that the used observations determine: one stereo
    observation or at least two observations."""
    P = len(problem.X_w)
    n_obs = np.bincount(problem.obs_pt[use], minlength=P)
    n_stereo = np.bincount(problem.obs_pt[use & stereo], minlength=P)
    return use & ((n_obs >= 2) | (n_stereo >= 1))[problem.obs_pt]


def static_chi2_depth(problem: BAProblem, T_c_w: np.ndarray, X_w: np.ndarray,
                      camera: StereoCamera) -> tuple[np.ndarray, np.ndarray]:
    """(M,) chi2 and depth of every observation of the window at the given estimate."""
    return chi2_depth(T_c_w, problem.obs_kf, X_w, problem.obs_pt, problem.meas, problem.inv_sigma2, camera)


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
    if (problem.kf_ids is None) != (problem.pt_ids is None):
        raise InputError("local_bundle_adjustment: kf_ids and pt_ids are given together or not at all")
    for name, ids, n in (("kf_ids", problem.kf_ids, K), ("pt_ids", problem.pt_ids, P)):
        if ids is not None and not (ids.shape == (n,) and (n == 0 or (ids.min() >= 0 and ids.max() < 2**31))
                                    and np.all(np.diff(ids) > 0)):
            raise InputError(f"local_bundle_adjustment: {name} must be ({n},), strictly increasing, in [0, 2^31)")
    if not (np.all(np.isfinite(problem.T_c_w)) and np.all(np.isfinite(problem.X_w))
            and np.all(np.isfinite(problem.meas)) and np.all(problem.inv_sigma2 > 0)):
        raise InputError("local_bundle_adjustment: poses, points and measurements must be finite, inv_sigma2 > 0")
