"""numpy <-> gtsam conversions, noise models and vectorized factor builders (the only gtsam glue).

gtsam's `Pose3` variables hold the camera pose in the world, `T_w_c` (body pose); our API speaks
`T_c_w`. Stereo observations are `[u, v, u_right]` with `u_right < 0` meaning monocular.
"""

from __future__ import annotations

import gtsam
import numpy as np

from dynaslam2.config import OptimConfig
from dynaslam2.geometry.camera import StereoCamera


def pose3_from_matrix(T: np.ndarray) -> gtsam.Pose3:
    """(4, 4) rigid transform -> gtsam.Pose3 (same transform)."""
    return gtsam.Pose3(np.asarray(T, dtype=float))


def matrix_from_pose3(pose3: gtsam.Pose3) -> np.ndarray:
    """gtsam.Pose3 -> (4, 4) rigid transform."""
    return np.asarray(pose3.matrix(), dtype=float)


def stereo_calibration(camera: StereoCamera) -> gtsam.Cal3_S2Stereo:
    """gtsam stereo calibration (fx, fy, skew 0, cx, cy, baseline)."""
    return gtsam.Cal3_S2Stereo(camera.fx, camera.fy, 0.0, camera.cx, camera.cy, camera.baseline)


def mono_calibration(camera: StereoCamera) -> gtsam.Cal3_S2:
    """gtsam pinhole calibration of the left camera."""
    return gtsam.Cal3_S2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy)


def huber_stereo_noise(inv_sigma2: float, delta: float | None,
                       disparity_weight: float | None = None) -> gtsam.noiseModel.Base:
    """3-dof noise of a `StereoPoint2` (u_L, u_R, v), sigma = 1/sqrt(inv_sigma2), wrapped in a Huber kernel
    (None: no kernel). Isotropic, or with `disparity_weight` k: u_R = u_L - d with the disparity d at
    sigma / k, i.e. the whitened residual [u, v, k disparity] of `reprojection.disparity_residuals`
    (covariance [[s2, s2, 0], [s2, s2 (1 + 1/k^2), 0], [0, 0, s2]])."""
    s2 = 1.0 / inv_sigma2
    if disparity_weight is None:
        return _robust(gtsam.noiseModel.Isotropic.Sigma(3, np.sqrt(s2)), delta)
    cov = s2 * np.array([[1.0, 1.0, 0.0], [1.0, 1.0 + disparity_weight**-2, 0.0], [0.0, 0.0, 1.0]])
    return _robust(gtsam.noiseModel.Gaussian.Covariance(cov), delta)


def _robust(model: gtsam.noiseModel.Base, delta: float | None) -> gtsam.noiseModel.Base:
    if delta is None:
        return model
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(delta), model)


def lm_params(cfg: OptimConfig, max_iterations: int, relative_error_tol: float,
              ordering_keys: np.ndarray | None = None,
              lambda_initial: float | None = None) -> gtsam.LevenbergMarquardtParams:
    """Levenberg-Marquardt settings from the config; `ordering_keys` (elimination order) is used when
    `cfg.ordering == "SCHUR"`, else gtsam computes COLAMD / METIS on the graph. `lambda_initial`
    replaces `cfg.lambda_initial` (local BA has its own)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setLinearSolverType(cfg.linear_solver)
    if cfg.ordering == "SCHUR" and ordering_keys is not None:
        params.setOrdering(gtsam.Ordering(ordering_keys.tolist()))
    else:
        params.setOrderingType("METIS" if cfg.ordering == "METIS" else "COLAMD")
    params.setRelativeErrorTol(relative_error_tol)
    params.setlambdaInitial(cfg.lambda_initial if lambda_initial is None else lambda_initial)
    params.setDiagonalDamping(cfg.diagonal_damping)
    params.setUseFixedLambdaFactor(cfg.lambda_fixed_factor)
    return params


def allocate_keys(*sizes: int) -> list[np.ndarray]:
    """Consecutive integer gtsam keys for blocks of variables: `allocate_keys(K, P)` -> [0..K-1], [K..K+P-1].

    Plain small integers (not gtsam.Symbol) so that key arrays can travel as float64 into gtsam's
    vectorized helpers; a later block (object poses, object points) just adds a size.
    """
    bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return [np.arange(a, b, dtype=np.int64) for a, b in zip(bounds[:-1], bounds[1:])]


def insert_poses(values: gtsam.Values, keys: np.ndarray, T: np.ndarray) -> None:
    """Insert (n, 4, 4) transforms as Pose3 values."""
    for key, T_k in zip(keys.tolist(), T):
        values.insert(key, pose3_from_matrix(T_k))


def insert_points(values: gtsam.Values, keys: np.ndarray, X: np.ndarray) -> None:
    """Insert (n, 3) points as Point3 values."""
    for key, X_j in zip(keys.tolist(), X):
        values.insertPoint3(key, X_j)


def extract_poses(values: gtsam.Values) -> np.ndarray:
    """(n, 4, 4) of every Pose3 in `values`, in key order."""
    rows = np.asarray(gtsam.utilities.extractPose3(values), dtype=float).reshape(-1, 12)
    T = np.zeros((len(rows), 4, 4))
    T[:, :3, :3] = rows[:, :9].reshape(-1, 3, 3)
    T[:, :3, 3] = rows[:, 9:]
    T[:, 3, 3] = 1.0
    return T


def extract_points(values: gtsam.Values) -> np.ndarray:
    """(n, 3) of every Point3 in `values`, in key order."""
    return np.asarray(gtsam.utilities.extractPoint3(values), dtype=float).reshape(-1, 3)


def add_stereo_projection_factors(
    graph: gtsam.NonlinearFactorGraph,
    pose_keys: np.ndarray,
    point_keys: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    camera: StereoCamera,
    huber_delta_mono: float | None,
    huber_delta_stereo: float | None,
) -> None:
    """Add one reprojection term per observation (pose key = `T_w_c` Pose3, point key = world Point3).

    Built in C++ by `gtsam.utilities.insertProjectionFactors` (one call per pose key, pyramid level and
    mono/stereo), ~10x faster than constructing `GenericStereoFactor3D`s in a Python loop. A stereo
    observation `[u, v, u_R]` becomes two built-in `GenericProjectionFactorCal3_S2`: the left camera
    on (u, v) and the right camera (body_P_sensor = +baseline along x) on (u_R, v), each with sigmas
    (s, s*sqrt(2)) so that v is counted once: the summed chi2 equals GenericStereoFactor3D's 3-dof
    chi2 exactly. With a kernel, Huber applies to each camera's 2-vector (delta per factor).
    """
    calib = mono_calibration(camera)
    right = gtsam.Pose3(gtsam.Rot3(), np.array([camera.baseline, 0.0, 0.0]))
    stereo = meas[:, 2] >= 0
    level_values, level = np.unique(inv_sigma2, return_inverse=True)
    group = (np.asarray(pose_keys, dtype=np.int64) * len(level_values) + level) * 2 + stereo
    order = np.argsort(group, kind="stable")
    groups, starts = np.unique(group[order], return_index=True)
    ends = np.append(starts[1:], len(order))
    point_keys_f = np.asarray(point_keys, dtype=np.float64)
    models: dict[tuple[int, bool], gtsam.noiseModel.Base] = {}
    for g, a, b in zip(groups.tolist(), starts.tolist(), ends.tolist()):
        idx = order[a:b]
        is_st = bool(g % 2)
        lvl = (g // 2) % len(level_values)
        pose_key = g // 2 // len(level_values)
        if (lvl, is_st) not in models:
            sigma = 1.0 / np.sqrt(level_values[lvl])
            if is_st:
                base = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma, sigma * np.sqrt(2.0)]))
                models[lvl, is_st] = _robust(base, huber_delta_stereo)
            else:
                models[lvl, is_st] = _robust(gtsam.noiseModel.Isotropic.Sigma(2, sigma), huber_delta_mono)
        model = models[lvl, is_st]
        keys = point_keys_f[idx]
        m = meas[idx]
        gtsam.utilities.insertProjectionFactors(graph, pose_key, keys, np.ascontiguousarray(m[:, :2].T), model, calib)
        if is_st:
            z_right = np.ascontiguousarray(m[:, [2, 1]].T)
            gtsam.utilities.insertProjectionFactors(graph, pose_key, keys, z_right, model, calib, right)


def stereo_factors(
    pose_keys: np.ndarray,
    point_keys: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    camera: StereoCamera,
    huber_delta: float | None,
    disparity_weight: float | None = None,
) -> np.ndarray:
    """(n,) object array of built-in `GenericStereoFactor3D`s (3-dof, Huber on the 3-vector as ORB-SLAM2's
    stereo edge), one per stereo observation `[u, v, u_R]` (noise: `huber_stereo_noise`).

    gtsam has no batch constructor for stereo factors: they are made in a Python loop (~3 us each here,
    ~2x the C++-built pairs of `add_stereo_projection_factors`), which the smaller graph repays (one
    3-row factor instead of two 2-row ones: 0.8x the LM time). Unlike the pairs, the Huber kernel sees
    the whole 3-dof stereo residual.
    """
    calib = stereo_calibration(camera)
    level_values, level = np.unique(inv_sigma2, return_inverse=True)
    models = [huber_stereo_noise(lv, huber_delta, disparity_weight) for lv in level_values.tolist()]
    factor, stereo_point = gtsam.GenericStereoFactor3D, gtsam.StereoPoint2
    out = np.empty(len(meas), dtype=object)
    for i, ((u, v, u_r), lvl, pose_key, point_key) in enumerate(zip(meas.tolist(), level.tolist(),
                                                                   pose_keys.tolist(), point_keys.tolist())):
        out[i] = factor(stereo_point(u, u_r, v), models[lvl], pose_key, point_key, calib)
    return out


class StereoFactorCache:
    """The stereo factors of the last local BA window, for the next one: consecutive windows share most
    observations, and a reused factor costs its `graph.add` (0.2 us) instead of its construction (~3 us).

    A factor is reused when its (pose key, point key), measurement, sigma, Huber delta and camera are
    the same, so the keys must name the same keyframe and point from call to call (stable ids, not
    window indices). Pose keys < 2^31, point keys < 2^32. Holds only the last window's factors; a call
    replaces its arrays (never writes into them), so `copy.copy` snapshots a cache.
    """

    def __init__(self) -> None:
        self._ids = np.zeros(0, dtype=np.int64)  # sorted (pose key << 32) | point key
        self._rows = np.zeros((0, 4))  # u, v, u_R, inv_sigma2 of each cached factor
        self._factors = np.empty(0, dtype=object)
        self._setting: tuple | None = None  # camera and Huber delta the factors were made with
        self.reused = 0  # factors reused by the last call

    def factors(self, pose_keys: np.ndarray, point_keys: np.ndarray, meas: np.ndarray, inv_sigma2: np.ndarray,
                camera: StereoCamera, huber_delta: float | None) -> np.ndarray:
        """`stereo_factors(...)`, reusing the cached ones that match; the cache then holds these."""
        pose_keys = np.asarray(pose_keys, dtype=np.int64)
        point_keys = np.asarray(point_keys, dtype=np.int64)
        if len(pose_keys) and (pose_keys.min() < 0 or pose_keys.max() >= 2**31 or point_keys.min() < 0
                               or point_keys.max() >= 2**32):
            raise ValueError("StereoFactorCache: pose keys must be in [0, 2^31), point keys in [0, 2^32)")
        setting = (camera.fx, camera.fy, camera.cx, camera.cy, camera.baseline, huber_delta)
        if setting != self._setting:
            self._ids, self._rows, self._factors = self._ids[:0], self._rows[:0], self._factors[:0]
        ids = (pose_keys << 32) | point_keys
        rows = np.column_stack([meas, inv_sigma2])
        out = np.empty(len(ids), dtype=object)
        hit = np.zeros(len(ids), dtype=bool)
        if len(self._ids):
            pos = np.minimum(np.searchsorted(self._ids, ids), len(self._ids) - 1)
            hit = (self._ids[pos] == ids) & np.all(self._rows[pos] == rows, axis=1)
            out[hit] = self._factors[pos[hit]]
        miss = ~hit
        out[miss] = stereo_factors(pose_keys[miss], point_keys[miss], meas[miss], inv_sigma2[miss], camera,
                                   huber_delta)
        order = np.argsort(ids, kind="stable")
        self._ids, self._rows, self._factors, self._setting = ids[order], rows[order], out[order], setting
        self.reused = int(hit.sum())
        return out


def add_stereo_factors(
    graph: gtsam.NonlinearFactorGraph,
    pose_keys: np.ndarray,
    point_keys: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    camera: StereoCamera,
    huber_delta_mono: float | None,
    huber_delta_stereo: float | None,
    cache: StereoFactorCache | None = None,
    disparity_weight: float | None = None,
) -> None:
    """Add one reprojection term per observation: a `GenericStereoFactor3D` per stereo observation
    (`stereo_factors`, or `cache.factors`; `disparity_weight`: see `huber_stereo_noise`), a pinhole
    projection factor per monocular one (built in C++ by `add_stereo_projection_factors`). Factors are
    added with `graph.add` (one pybind overload, 0.2 us), not `push_back` (two overloads, the graph one
    tried first: 2 us per factor)."""
    stereo = meas[:, 2] >= 0
    mono = ~stereo
    add_stereo_projection_factors(graph, pose_keys[mono], point_keys[mono], meas[mono], inv_sigma2[mono], camera,
                                  huber_delta_mono, None)
    if cache is not None and disparity_weight is not None:
        raise ValueError("add_stereo_factors: the factor cache holds isotropic factors only")
    stereo_args = (pose_keys[stereo], point_keys[stereo], meas[stereo], inv_sigma2[stereo], camera, huber_delta_stereo)
    factors = (stereo_factors(*stereo_args, disparity_weight) if cache is None else cache.factors(*stereo_args))
    add = graph.add
    for factor in factors:
        add(factor)
