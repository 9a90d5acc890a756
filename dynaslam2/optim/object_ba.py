"""Local bundle adjustment with objects (paper III-D, eq. 1-6), on plain arrays.

Variables (gtsam keys in blocks, `allocate_keys`): keyframe poses T_w_c, static points X_w, one pose
per object observation (object k seen at keyframe i), one velocity (v_o, w_o) per object observation
that has a neighbour in time, and the object points X_o stored once in their object frame:
N' = 6 Nc + 6 Nc No + 3 No Nop (+ 6 per velocity), paper III-C.

Object pose parametrization (`cfg.objects.parametrization`):
- "camera_in_object" (default): the variable is the camera pose in the object frame Q = T_o_c =
  T_w_o^-1 T_w_c, so that eq. (2), u - pi(T_c_w T_w_o x_o) = u - pi(Q^-1 x_o), is gtsam's built-in
  GenericStereoFactor3D (pinhole factor if monocular) on (Q, x_o) (`add_stereo_factors`, as the
  static eq. (1) terms and local_ba); T_w_o = T_w_c Q^-1 is recovered afterwards and eq. (4) sees
  it through (T_w_c, Q). A bijective change of variables for given cameras: same objective, same
  optimum.
- "direct": T_w_o is the variable and eq. (2) a Python factor per object observation on
  (T_w_c, T_w_o, x_o) (object_factors.direct_projection_factor): the reference formulation.

Terms: eq. (1) static reprojection, eq. (2) object reprojection (sigma from the pyramid level; a stereo
observation's disparity at sigma / `cfg.objects.disparity_weight`, as the object pose-only optimization's),
eq. (3) velocity smoothness (built-in BetweenFactorVector, sigmas sigma_*_acc * dt), eq. (4)-(5)
velocity/pose/point coupling (object_factors.motion_factor_object: one factor per object, 12 rows per
frame pair; `motion_factor` per frame pair as reference, sigma sigma_motion_xyz * dt). Huber on
every term. Reprojection terms follow local_ba's schedule (Huber stage, chi2 outlier removal, stage
without kernel); eq. (3)-(4) keep their Huber kernel in both stages.

Gauge: the world by the fixed keyframes (the first keyframe when none is fixed and static structure
is optimized); each object frame by holding (strong prior) its observations at fixed keyframes, or,
when it has none, its earliest observation in the window: in "camera_in_object" the held variable
is Q (the object pose relative to that camera), in "direct" T_w_o; the two gauges coincide when the
anchoring keyframe is fixed. A measured observation whose reprojection terms are nearly all of points seen
only there in the window is held too (`optim.objects.hold_single_view_observations`, `_held_observations`).

The three cases of III-D: `optimize_static and not optimize_objects` (camera weak only) is the static
local BA (`local_bundle_adjustment`, objects untouched); `optimize_objects and not optimize_static`
(object weak only) frees the object variables and the non-fixed cameras (the caller frees the
keyframes of the last `cfg.objects.tail_seconds`, `temporal_tail`), the static points being
constants (one pose-only factor per camera); both: everything jointly.

Both, with `cfg.objects.static_reduced` (the default): the static terms (eq. 1) are linearized once at
the window's estimate (Huber weights there; after the static local BA, its outliers erased, when the
caller's `objects.static_ba_first`) and reduced to the free cameras by
eliminating the static points (optim/static_schur.py, each point block damped by
`static_point_damping`): one factor on the cameras holding the quadratic model of the static cost.
LM then iterates on the cameras and the objects only, and the static points follow the cameras'
increments by back-substitution at the end; no static outlier is reclassified between the stages.
A stated departure from relinearizing every static term at every iteration (`static_reduced=False`,
the exact joint problem of III-D): a SLAM window starts near its optimum (the new keyframe from
tracking, the others from earlier BAs), where one linearization is what the static local BA's single
LM iteration uses too, and the objects move the cameras by ~mm. From a window with its newest keyframe
1 cm off, or after a converged static BA, both reach the
same cameras and objects (tests/test_object_ba.py); on captured SLAM windows (traffic s0, following
s0) the reduced form ends ~4x closer to the converged exact optimum than the exact form with
ORB-SLAM2's iteration budget (cameras: median 0.6 / 0.4 mm against 2.5 / 1.8 mm; final cost median
2.6 / 2.2 against 4.3 / 4.6 above the converged one). End to end the two are equally accurate (config.py).

With `cfg.objects.object_points_reduced` (opt-in), eq. (2) is reduced the same way to the object
observations' poses Q (the observations as static_schur's cameras, the object points eliminated, each point
block damped by `lambda_initial` as in the exact form's first LM step; one factor per object: no point is
seen from two objects), relinearized at each stage's start (the objects move more than the cameras between
the two stages), the points following by back-substitution after each stage. Near the optimum it reaches the
exact one (tests/test_object_ba.py); on the 71 windows of traffic s0 with every object in the BA
(objects.kf_points_all_objects and ba_all_objects: ~5 objects, ~650 object points, ~2300 object observations
per window) it takes 0.79x the CPU time of the object points as gtsam variables at a summed final cost of
344389 against 344289; on the default's 45 windows (~100 object points) no gain (0.98x).

Cost (this shared 2-core machine under load ~9, CPU time; windows saved by `bench_object_ba.py
--capture` from 640x480 150-frame dynamic runs, replayed with `--compare` interleaved in one process).
Joint windows (up to 30 keyframes, ~4000 static points, ~20k static and 20-600 object observations),
median exact -> reduced: traffic s0 (35 windows) 286 -> 67 ms, traffic s1 (11) 283 -> 63 ms, following
s0 (18) 299 -> 73 ms (B/A 0.23-0.24), the reduced final cost lower on 62 of the 64; all windows with
objects (object-weak ones unchanged, ~10-40 ms): median 248 -> 61, 29 -> 27, 293 -> 72 ms. Of the
reduced joint BA, the static reduction is ~1/2 (per-observation Jacobians and normal blocks in numpy
~2/3 of it, the block-sparse product ~1/4), LM on cameras and objects (3-4 iterations, the eq. (4)
Python factors ~1/4 of it) ~1/5, the chi2 and cost evaluations of the static observations ~1/5. The
exact joint form spends ~60% of each LM iteration in gtsam's elimination of the ~4000 points and
~100 ms building the robust stage's stereo factors (the refine stage: C++-built projection pairs).
Synthetic window (`bench_object_ba.py`: 10 keyframes, 1500 static points, 4 objects x 80 points, no
static BA first: exact form): ~0.6 s for the joint BA against ~0.25 s for the static local BA, ~0.4 s
for object-weak only; the "direct" eq. (2) form ~5x slower, eq. (4) with the points as variables ~5x
slower. Object-weak only: half of each iteration is the Python factors (one pose-only factor per
camera, ~0.8 ms per linearization).
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
    add_stereo_factors,
    add_stereo_projection_factors,
    allocate_keys,
    extract_points,
    extract_poses,
    insert_points,
    insert_poses,
    lm_params,
)
from dynaslam2.optim.local_ba import (
    FIXED_POSE_SIGMA,
    BAProblem,
    determined_observations,
    local_bundle_adjustment,
    static_chi2_depth,
)
from dynaslam2.optim.object_factors import (
    direct_projection_factor,
    motion_factor,
    motion_factor_object,
    motion_affine,
    motion_cost,
)
from dynaslam2.optim.pose_only import pose_only_factor
from dynaslam2.optim.reprojection import chi2_depth, chi2_thresholds, huber_cost, is_stereo
from dynaslam2.optim.static_schur import StaticSchur, static_schur
from dynaslam2.time_windows import within


@dataclass
class ObjectBAProblem(BAProblem):
    """A local BA window with objects: the static `BAProblem` fields plus object observations.

    An object observation f is object `obj_id[f]` seen at keyframe `obj_frames[f]` (at most one per
    object and keyframe), with pose `T_w_o[f]` and velocity (`v_o[f]`, `w_o[f]`) in its object frame.
    Object point q (`X_o[q]`, object frame of object `pt_obj[q]`) is observed in object observation
    `oobs_f[m]` as `oobs_meas[m]` = [u, v, u_right] (u_right < 0: monocular).
    """

    obj_frames: np.ndarray  # (F,) int keyframe index of each object observation
    obj_id: np.ndarray  # (F,) int object index
    T_w_o: np.ndarray  # (F, 4, 4) initial object poses
    v_o: np.ndarray  # (F, 3) initial linear velocities (object frame, m/s)
    w_o: np.ndarray  # (F, 3) initial angular velocities (object frame, rad/s)
    timestamps: np.ndarray  # (K,) keyframe times, s
    X_o: np.ndarray  # (P2, 3) object points in their object frame
    pt_obj: np.ndarray  # (P2,) object index of each object point
    oobs_f: np.ndarray  # (M2,) index into the object observations
    oobs_pt: np.ndarray  # (M2,) index into X_o
    oobs_meas: np.ndarray  # (M2, 3)
    oobs_inv_sigma2: np.ndarray  # (M2,)
    obj_measured: np.ndarray | None = None  # (F,) bool: the tracker measured the pose (not its prediction); None: all
    optimize_static: bool = True  # static points are variables (else constants constraining the cameras)
    optimize_objects: bool = True  # object poses, velocities and points are variables (else untouched)


@dataclass
class ObjectBAResult:
    """Optimized window. `inlier` / `obj_inlier`: the static / object observation passes the chi2 and
    positive-depth tests at the end. Errors: summed Huber costs of all terms (reprojection with the
    chi2 deltas, eq. 3 and 4 whitened) at the input and at the output. `n_parameters`: degrees of
    freedom of each variable block in the first stage (paper III-C)."""

    T_c_w: np.ndarray
    X_w: np.ndarray
    inlier: np.ndarray
    T_w_o: np.ndarray
    v_o: np.ndarray
    w_o: np.ndarray
    X_o: np.ndarray
    obj_inlier: np.ndarray
    iterations: int
    initial_error: float
    final_error: float
    timings_ms: dict[str, float] = field(default_factory=dict)  # "build", "solve"
    n_parameters: dict[str, int] = field(default_factory=dict)


@dataclass
class _Estimate:
    T_c_w: np.ndarray
    X_w: np.ndarray
    T_w_o: np.ndarray
    velocity: np.ndarray  # (F, 6) = (v_o, w_o)
    X_o: np.ndarray


@dataclass
class _ObjectStructure:
    """Which object variables take part: observations, points, frame pairs (consecutive in time)."""

    obs: np.ndarray  # (F,) bool: the observation's pose is a variable
    points: np.ndarray  # (P2,) bool: the point is a variable
    use: np.ndarray  # (M2,) bool: the observation's reprojection term is used
    pair_a: np.ndarray  # (R,) earlier observation of each pair
    pair_b: np.ndarray  # (R,) later observation
    pair_dt: np.ndarray  # (R,) s
    moving: np.ndarray  # (F,) bool: the observation has a velocity variable (it belongs to a pair)


def temporal_tail(timestamps: np.ndarray, tail_seconds: float) -> np.ndarray:
    """(K,) bool: keyframes within `tail_seconds` of the newest one (the free cameras of the
    object-weak BA, paper III-D)."""
    timestamps = np.asarray(timestamps, dtype=float)
    return within(timestamps.max() - timestamps, tail_seconds)


def object_bundle_adjustment(problem: ObjectBAProblem, camera: StereoCamera, cfg: OptimConfig) -> ObjectBAResult:
    """Bundle adjustment with objects (eq. 6): `cfg.ba_iterations_robust` LM iterations with Huber,
    removal of reprojection outliers (chi2 > 7.815 stereo / 5.991 mono, or behind the camera), then
    `cfg.ba_iterations_refine` iterations without kernel on the reprojection terms."""
    _check(problem)
    t_start = time.perf_counter()
    est = _Estimate(problem.T_c_w.astype(float).copy(), problem.X_w.astype(float).copy(),
                    problem.T_w_o.astype(float).copy(), np.hstack([problem.v_o, problem.w_o]).astype(float),
                    problem.X_o.astype(float).copy())
    if problem.optimize_static and not problem.optimize_objects:
        return _camera_weak_only(problem, est, camera, cfg)
    fixed = problem.fixed.astype(bool).copy()
    if problem.optimize_static and not fixed.any():
        fixed[0] = True
    th = chi2_thresholds(problem.meas, cfg.chi2_mono, cfg.chi2_stereo)
    th_o = chi2_thresholds(problem.oobs_meas, cfg.chi2_mono, cfg.chi2_stereo)
    use = np.ones(len(problem.obs_kf), dtype=bool)
    use_o = np.full(len(problem.oobs_f), problem.optimize_objects)
    structure = _object_structure(problem, use_o, cfg.objects.min_observation_points)
    c2, depth = static_chi2_depth(problem, est.T_c_w, est.X_w, camera)
    initial_error = _total_cost(problem, est, structure, camera, cfg, c2)
    schur = None
    if problem.optimize_static and cfg.objects.static_reduced:
        schur, use = _static_reduction(problem, est, fixed, th, depth, camera, cfg)
        T_w_c0, X_w0 = inverse(est.T_c_w[schur.cams]), est.X_w.copy()  # the linearization point
    timings_ms = {"build": 1e3 * (time.perf_counter() - t_start), "solve": 0.0}
    iterations = 0
    n_parameters: dict[str, int] = {}
    for robust, n_iter in ((True, cfg.ba_iterations_robust), (False, cfg.ba_iterations_refine)):
        if not robust and n_iter == 0:
            break  # no refine stage: the final classification below removes the outliers
        if not robust:
            if schur is None:  # (reduced: the static terms keep their linearization at the start)
                c2, depth = static_chi2_depth(problem, est.T_c_w, est.X_w, camera)
                use = (c2 <= th) & (depth > cfg.min_depth)
            if problem.optimize_objects:
                c2_o, depth_o = _object_chi2_depth(problem, est, camera, cfg)
                use_o = (c2_o <= th_o) & (depth_o > cfg.min_depth)
            structure = _object_structure(problem, use_o, cfg.objects.min_observation_points)
        if n_iter == 0:
            continue
        t_build = time.perf_counter()
        held = _held_observations(problem, structure, fixed, cfg)
        object_schur = (_object_reduction(problem, est, structure, held, th_o if robust else None, camera, cfg)
                        if cfg.objects.object_points_reduced else None)
        graph, values, keys, ordering = _build(problem, est, fixed, use, structure, held, robust, camera, cfg,
                                               None if schur is None else (schur, T_w_c0), object_schur)
        if not n_parameters:
            n_parameters = {name: int(len(members) * dof) for name, (members, _, dof) in keys.items()}
        if graph.size() == 0:
            continue
        optimizer = gtsam.LevenbergMarquardtOptimizer(
            graph, values, lm_params(cfg, n_iter, cfg.ba_relative_error_tol, ordering, cfg.objects.lambda_initial))
        t_solve = time.perf_counter()
        values = optimizer.optimize()
        timings_ms["build"] += 1e3 * (t_solve - t_build)
        timings_ms["solve"] += 1e3 * (time.perf_counter() - t_solve)
        iterations += optimizer.iterations()
        _read_back(values, keys, problem, cfg, est)
        if object_schur is not None:  # the object points by back-substitution from this stage's start
            object_reduced, Q0 = object_schur
            Q = inverse(est.T_c_w[problem.obj_frames[object_reduced.cams]] @ est.T_w_o[object_reduced.cams])
            est.X_o[object_reduced.points] += object_reduced.point_steps(_local_coordinates(Q0, Q))

    if schur is not None:  # the static points by back-substitution from the start (unused between stages)
        est.X_w[schur.points] = X_w0[schur.points] + schur.point_steps(
            _local_coordinates(T_w_c0, inverse(est.T_c_w[schur.cams])))
    est.T_c_w[fixed] = problem.T_c_w[fixed]
    c2, depth = static_chi2_depth(problem, est.T_c_w, est.X_w, camera)
    c2_o, depth_o = _object_chi2_depth(problem, est, camera, cfg)
    return ObjectBAResult(
        T_c_w=est.T_c_w, X_w=est.X_w, inlier=(c2 <= th) & (depth > cfg.min_depth),
        T_w_o=est.T_w_o, v_o=est.velocity[:, :3].copy(), w_o=est.velocity[:, 3:].copy(), X_o=est.X_o,
        obj_inlier=(c2_o <= th_o) & (depth_o > cfg.min_depth), iterations=iterations,
        initial_error=initial_error, final_error=_total_cost(problem, est, structure, camera, cfg, c2, c2_o),
        timings_ms=timings_ms, n_parameters=n_parameters)


def _camera_weak_only(problem: ObjectBAProblem, est: _Estimate, camera: StereoCamera,
                      cfg: OptimConfig) -> ObjectBAResult:
    """III-D, camera tracking weak only: ORB-SLAM2's local BA on the static structure, objects untouched."""
    static = local_bundle_adjustment(BAProblem(problem.T_c_w, problem.fixed, problem.X_w, problem.obs_kf,
                                               problem.obs_pt, problem.meas, problem.inv_sigma2), camera, cfg)
    est.T_c_w, est.X_w = static.T_c_w, static.X_w
    c2_o, depth_o = _object_chi2_depth(problem, est, camera, cfg)
    th_o = chi2_thresholds(problem.oobs_meas, cfg.chi2_mono, cfg.chi2_stereo)
    return ObjectBAResult(
        T_c_w=est.T_c_w, X_w=est.X_w, inlier=static.inlier, T_w_o=est.T_w_o, v_o=est.velocity[:, :3].copy(),
        w_o=est.velocity[:, 3:].copy(), X_o=est.X_o, obj_inlier=(c2_o <= th_o) & (depth_o > cfg.min_depth),
        iterations=static.iterations, initial_error=static.initial_error, final_error=static.final_error,
        timings_ms=static.timings_ms, n_parameters={})


def _object_structure(problem: ObjectBAProblem, use_o: np.ndarray, min_points: int) -> _ObjectStructure:
    """Reprojection terms: the used observations of determined points (one stereo or two observations)
    in object observations with at least `min_points` of them. Every observation of an object with
    at least one such observation is a variable: one with fewer terms follows the motion model (eq. 3-5)
    through its neighbours in time. Pairs: consecutive observations of each object."""
    F, P2 = len(problem.obj_frames), len(problem.X_o)
    stereo = is_stereo(problem.oobs_meas)
    strong = np.ones(F, dtype=bool)
    for _ in range(4):  # observations and points determine each other; a few passes reach the fixed point
        use = use_o & strong[problem.oobs_f]
        n_obs = np.bincount(problem.oobs_pt[use], minlength=P2)
        n_stereo = np.bincount(problem.oobs_pt[use & stereo], minlength=P2)
        points = (n_obs >= 2) | (n_stereo >= 1)
        use &= points[problem.oobs_pt]
        new_strong = strong & (np.bincount(problem.oobs_f[use], minlength=F) >= min_points)
        if np.array_equal(new_strong, strong):
            break
        strong = new_strong
    use &= strong[problem.oobs_f]
    points = np.bincount(problem.oobs_pt[use], minlength=P2) > 0
    tracked = np.zeros(int(problem.obj_id.max(initial=-1)) + 1, dtype=bool)
    tracked[problem.obj_id[strong]] = True
    obs = tracked[problem.obj_id]
    idx = np.flatnonzero(obs)
    order = idx[np.lexsort((problem.timestamps[problem.obj_frames[idx]], problem.obj_id[idx]))]
    same = problem.obj_id[order[1:]] == problem.obj_id[order[:-1]]
    pair_a, pair_b = order[:-1][same], order[1:][same]
    pair_dt = problem.timestamps[problem.obj_frames[pair_b]] - problem.timestamps[problem.obj_frames[pair_a]]
    moving = np.zeros(F, dtype=bool)
    moving[pair_a] = moving[pair_b] = True
    return _ObjectStructure(obs, points, use, pair_a, pair_b, pair_dt, moving)


def _held_observations(problem: ObjectBAProblem, st: _ObjectStructure, fixed: np.ndarray,
                       cfg: OptimConfig) -> np.ndarray:
    """(F,) bool: the object observations whose pose is held (strong prior): the gauge of each object frame
    (its observations at fixed keyframes, or when it has none, its earliest one in the window) and, with
    `cfg.objects.hold_single_view_observations`, each measured observation (`obj_measured`) with reprojection terms
    of which fewer than `min_observation_points` are of points seen at another observation of the window. Its pose
    is the tracker's, measured on points whose other observations are outside the window (non-keyframes); eq. (2)
    cannot move it (its single-view points follow it), and eq. (3)-(4) alone would bend it to the window's
    motion: a car turning out of an occlusion straightened 6 -> 18 deg of rotation error, its points carried
    along (crossing s99, f33)."""
    held = st.obs & fixed[problem.obj_frames]
    for k in np.unique(problem.obj_id[st.obs & ~held]).tolist():
        mine = np.flatnonzero(st.obs & (problem.obj_id == k))
        if not held[mine].any():
            held[mine[np.argmin(problem.timestamps[problem.obj_frames[mine]])]] = True
    if cfg.objects.hold_single_view_observations:
        F, min_points = len(problem.obj_frames), cfg.objects.min_observation_points
        n_views = np.bincount(problem.oobs_pt[st.use], minlength=len(problem.X_o))
        multi_view = st.use & (n_views[problem.oobs_pt] >= 2)
        measured = np.ones(F, dtype=bool) if problem.obj_measured is None else problem.obj_measured.astype(bool)
        held |= (st.obs & measured & (np.bincount(problem.oobs_f[st.use], minlength=F) >= min_points)
                 & (np.bincount(problem.oobs_f[multi_view], minlength=F) < min_points))
    return held


def _object_reduction(problem: ObjectBAProblem, est: _Estimate, st: _ObjectStructure, held: np.ndarray,
                      delta2: np.ndarray | None, camera: StereoCamera,
                      cfg: OptimConfig) -> tuple[StaticSchur, np.ndarray] | None:
    """eq. (2) linearized at the current estimate (Huber weights there; `delta2`: (M2,) deltas^2, None: no
    kernel) and reduced to the poses Q = T_o_c of the free object observations by eliminating the object
    points (`cfg.objects.object_points_reduced`), as the static terms to the cameras (static_schur.py, the
    observations as its cameras); the held observations are constants there. Each point block is damped by
    LM's initial lambda of the exact form (`cfg.objects.lambda_initial`, whitened units), the damping its
    points see in that form's first step: with static_point_damping's 1e-4 the points moved far more than
    there (traffic s0's windows: stereo-seen points p95 0.65 m against 0.32, points seen without depth up to
    61 m), and end to end the object ATE rose (crossing 55-69 / 70-84 0.235 / 0.309 -> 0.400 / 0.380 m with
    both all-objects options). No point is seen from two objects: the system is block-diagonal
    per object (`StaticSchur.factors`). Returns the reduction and Q at the linearization point (None
    when no observation is free)."""
    T_c_o = est.T_c_w[problem.obj_frames] @ est.T_w_o
    free = st.obs & ~held & (np.bincount(problem.oobs_f[st.use], minlength=len(held)) > 0)
    if not free.any():
        return None
    use = st.use
    reduced = static_schur(T_c_o, free, est.X_o, problem.oobs_f[use], problem.oobs_pt[use], problem.oobs_meas[use],
                           problem.oobs_inv_sigma2[use], camera, cfg.min_depth, None if delta2 is None else delta2[use],
                           cfg.objects.lambda_initial, _disparity_weight(cfg))
    return reduced, inverse(T_c_o[reduced.cams])


def _local_coordinates(T0: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(n, 6) Local(T0_i, T_i) = Log(T0_i^-1 T_i), gtsam's (omega, nu) order."""
    return np.array([gtsam.Pose3(a).localCoordinates(gtsam.Pose3(b)) for a, b in zip(T0, T)]).reshape(-1, 6)


def _build(problem: ObjectBAProblem, est: _Estimate, fixed: np.ndarray, use: np.ndarray, st: _ObjectStructure,
           held: np.ndarray, robust: bool, camera: StereoCamera, cfg: OptimConfig,
           reduced: tuple[StaticSchur, np.ndarray] | None = None,
           object_reduced: tuple[StaticSchur, np.ndarray] | None = None):
    """Graph, initial values, {block: (member indices, their keys, dof)}, SCHUR elimination order.
    `held`: the object observations whose pose is held (`_held_observations`). `reduced`: the static terms
    as their reduced camera system (and its linearization point T_w_c) instead of static point variables
    and eq. (1) factors; `object_reduced`: eq. (2) likewise per object (`_object_reduction`), the object
    points then no variables."""
    ocfg = cfg.objects
    direct = ocfg.parametrization == "direct"
    disparity_weight = _disparity_weight(cfg)
    delta_mono = np.sqrt(cfg.chi2_mono) if robust else None
    delta_stereo = np.sqrt(cfg.chi2_stereo) if robust else None
    # Huber on the whole 3-dof stereo residual needs the Python-built stereo factors; without kernel the
    # C++-built projection pairs have exactly the same cost at a fraction of the build time (as local_ba)
    add_reprojection = add_stereo_factors if robust else add_stereo_projection_factors
    K = len(est.T_c_w)
    stereo = is_stereo(problem.meas)
    # static points: variables (determined ones) or constants in per-camera pose-only factors
    if problem.optimize_static and reduced is None:
        n_obs = np.bincount(problem.obs_pt[use], minlength=len(est.X_w))
        n_st = np.bincount(problem.obs_pt[use & stereo], minlength=len(est.X_w))
        static_pts = np.flatnonzero((n_obs >= 2) | (n_st >= 1))
        use = use & np.isin(problem.obs_pt, static_pts)
    else:
        static_pts = np.zeros(0, dtype=np.int64)
    used_kf = np.bincount(problem.obs_kf[use], minlength=K) > 0
    used_kf |= np.bincount(problem.obj_frames[st.obs], minlength=K) > 0
    cams = np.flatnonzero(used_kf | fixed)
    obs_idx, moving_idx, obj_pts = np.flatnonzero(st.obs), np.flatnonzero(st.moving), np.flatnonzero(st.points)
    point_vars = obj_pts if object_reduced is None else obj_pts[:0]  # (eq. 4 reads every point, as constants)
    cam_keys, obs_keys, spt_keys, opt_keys, vel_keys = allocate_keys(len(cams), len(obs_idx), len(static_pts),
                                                                    len(point_vars), len(moving_idx))
    cam_key = _key_map(K, cams, cam_keys)
    obs_key = _key_map(len(est.T_w_o), obs_idx, obs_keys)
    spt_key = _key_map(len(est.X_w), static_pts, spt_keys)
    opt_key = _key_map(len(est.X_o), point_vars, opt_keys)
    vel_key = _key_map(len(est.T_w_o), moving_idx, vel_keys)

    values = gtsam.Values()
    T_w_c = inverse(est.T_c_w)
    insert_poses(values, cam_keys, T_w_c[cams])
    obj_frame = problem.obj_frames[obs_idx]
    insert_poses(values, obs_keys, est.T_w_o[obs_idx] if direct else inverse(est.T_w_o[obs_idx]) @ T_w_c[obj_frame])
    insert_points(values, spt_keys, est.X_w[static_pts])
    insert_points(values, opt_keys, est.X_o[point_vars])
    for key, velocity in zip(vel_keys.tolist(), est.velocity[moving_idx]):
        values.insert(key, velocity)

    graph = gtsam.NonlinearFactorGraph()
    prior = gtsam.noiseModel.Isotropic.Sigma(6, FIXED_POSE_SIGMA)
    for key in cam_keys[fixed[cams]].tolist():
        graph.addPriorPose3(key, values.atPose3(key), prior)
    # eq. (1)
    if reduced is not None:
        graph.push_back(reduced[0].factor(cam_key[reduced[0].cams], reduced[1]))
    elif problem.optimize_static:
        add_reprojection(graph, cam_key[problem.obs_kf[use]], spt_key[problem.obs_pt[use]],
                         problem.meas[use], problem.inv_sigma2[use], camera, delta_mono, delta_stereo)
    else:
        th = chi2_thresholds(problem.meas, cfg.chi2_mono, cfg.chi2_stereo)
        for kf in cams[~fixed[cams]].tolist():
            sel = use & (problem.obs_kf == kf)
            if sel.any():
                graph.push_back(pose_only_factor(int(cam_key[kf]), est.X_w[problem.obs_pt[sel]], problem.meas[sel],
                                                 problem.inv_sigma2[sel], th[sel] if robust else None, camera,
                                                 cfg.min_depth))
    # eq. (2)
    if direct:
        for f in obs_idx.tolist():
            sel = st.use & (problem.oobs_f == f)
            graph.push_back(direct_projection_factor(
                int(cam_key[problem.obj_frames[f]]), int(obs_key[f]), opt_key[problem.oobs_pt[sel]],
                problem.oobs_meas[sel], problem.oobs_inv_sigma2[sel], camera, delta_mono, delta_stereo,
                disparity_weight))
    elif object_reduced is not None:
        object_schur, Q0 = object_reduced
        for factor in object_schur.factors(obs_key[object_schur.cams], Q0, problem.obj_id[object_schur.cams]):
            graph.push_back(factor)
    elif st.use.any():
        # (both stages as GenericStereoFactor3D with the disparity model: the C++-built pairs cannot correlate)
        obj_args = (graph, obs_key[problem.oobs_f[st.use]], opt_key[problem.oobs_pt[st.use]], problem.oobs_meas[st.use],
                    problem.oobs_inv_sigma2[st.use], camera, delta_mono, delta_stereo)
        if disparity_weight is None:
            add_reprojection(*obj_args)
        else:
            add_stereo_factors(*obj_args, disparity_weight=disparity_weight)
    # gauge of each object frame
    for f in np.flatnonzero(held).tolist():
        graph.addPriorPose3(int(obs_key[f]), values.atPose3(int(obs_key[f])), prior)
    # eq. (3) and eq. (4)-(5), per object per consecutive pair of observations
    huber_velocity = gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(ocfg.chi2_velocity))
    motion_keys = np.column_stack([obs_key[st.pair_a], obs_key[st.pair_b], vel_key[st.pair_a]]) if direct else \
        np.column_stack([cam_key[problem.obj_frames[st.pair_a]], cam_key[problem.obj_frames[st.pair_b]],
                         obs_key[st.pair_a], obs_key[st.pair_b], vel_key[st.pair_a]])
    for a, b, dt in zip(st.pair_a.tolist(), st.pair_b.tolist(), st.pair_dt.tolist()):
        sigmas = np.repeat([ocfg.sigma_linear_acc * dt, ocfg.sigma_angular_acc * dt], 3)
        model = gtsam.noiseModel.Robust.Create(huber_velocity, gtsam.noiseModel.Diagonal.Sigmas(sigmas))
        graph.push_back(gtsam.BetweenFactorVector(int(vel_key[a]), int(vel_key[b]), np.zeros(6), model))
    pair_obj = problem.obj_id[st.pair_a]
    for k in np.unique(pair_obj).tolist():
        pts = obj_pts[problem.pt_obj[obj_pts] == k]
        mine = np.flatnonzero(pair_obj == k)
        if ocfg.motion_form == "moments" and not ocfg.motion_points_variable:
            graph.push_back(motion_factor_object(motion_keys[mine], ocfg.parametrization, st.pair_dt[mine],
                                                 ocfg.sigma_motion_xyz * st.pair_dt[mine], ocfg.chi2_motion,
                                                 est.X_o[pts].copy()))
            continue
        for r in mine.tolist():
            dt = float(st.pair_dt[r])
            graph.push_back(motion_factor(motion_keys[r].tolist(), ocfg.parametrization, dt, ocfg.sigma_motion_xyz * dt,
                                          ocfg.chi2_motion, **({"point_keys": opt_key[pts]} if ocfg.motion_points_variable
                                                               else {"X_o": est.X_o[pts].copy()})))
    keys = {"camera": (cams, cam_keys, 6), "object_pose": (obs_idx, obs_keys, 6),
            "static_point": (static_pts, spt_keys, 3), "object_point": (point_vars, opt_keys, 3),
            "velocity": (moving_idx, vel_keys, 6)}
    # points, then each object's velocities and poses (a clique per object), then the cameras
    object_keys = np.concatenate([vel_keys, obs_keys])
    object_of_key = np.concatenate([problem.obj_id[moving_idx], problem.obj_id[obs_idx]])
    ordering = np.concatenate([spt_keys, opt_keys, object_keys[np.argsort(object_of_key, kind="stable")], cam_keys])
    return graph, values, keys, ordering


def _static_reduction(problem: ObjectBAProblem, est: _Estimate, fixed: np.ndarray, th: np.ndarray, depth: np.ndarray,
                      camera: StereoCamera, cfg: OptimConfig) -> tuple[StaticSchur, np.ndarray]:
    """The static terms of the joint case reduced to the free cameras at the current estimate (`depth`: of
    each static observation there), with the Huber kernel (`cfg.objects.static_reduced`); also the (M,)
    static observations it uses: in front of the camera, of determined points."""
    use = determined_observations(problem, depth > cfg.min_depth, is_stereo(problem.meas))
    free = ~fixed & (np.bincount(problem.obs_kf[use], minlength=len(fixed)) > 0)
    schur = static_schur(est.T_c_w, free, est.X_w, problem.obs_kf[use], problem.obs_pt[use], problem.meas[use],
                         problem.inv_sigma2[use], camera, cfg.min_depth, th[use], cfg.objects.static_point_damping)
    return schur, use


def _key_map(n: int, members: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """(n,) gtsam key of each member index, -1 elsewhere."""
    key = np.full(n, -1, dtype=np.int64)
    key[members] = keys
    return key


def _read_back(values: gtsam.Values, keys: dict, problem: ObjectBAProblem,
               cfg: OptimConfig, est: _Estimate) -> None:
    """Copy the optimized variables into `est` (T_w_o = T_w_c Q^-1 in the camera_in_object form)."""
    cams, _, _ = keys["camera"]
    obs_idx, _, _ = keys["object_pose"]
    static_pts, _, _ = keys["static_point"]
    obj_pts, _, _ = keys["object_point"]
    moving_idx, vel_keys, _ = keys["velocity"]
    poses = extract_poses(values)  # keys in order: cameras, then object poses
    T_w_c = poses[:len(cams)]
    est.T_c_w[cams] = inverse(T_w_c)
    obj_poses = poses[len(cams):]
    if cfg.objects.parametrization == "direct":
        est.T_w_o[obs_idx] = obj_poses
    else:
        est.T_w_o[obs_idx] = inverse(est.T_c_w[problem.obj_frames[obs_idx]]) @ inverse(obj_poses)
    # Point3 values in key order (static, then object points); gtsam appends one unset row per
    # non-3 Vector value (the velocities) after them
    points = extract_points(values)[:len(static_pts) + len(obj_pts)]
    est.X_w[static_pts] = points[:len(static_pts)]
    est.X_o[obj_pts] = points[len(static_pts):]  # (none when `_object_reduction` eliminated them)
    if len(moving_idx):
        est.velocity[moving_idx] = np.array([values.atVector(k) for k in vel_keys.tolist()])


def _disparity_weight(cfg: OptimConfig) -> float | None:
    """eq. (2)'s disparity weight (`cfg.objects.disparity_weight`; None: isotropic [u, v, u_right])."""
    return cfg.objects.disparity_weight or None


def _object_chi2_depth(problem: ObjectBAProblem, est: _Estimate, camera: StereoCamera,
                       cfg: OptimConfig) -> tuple[np.ndarray, np.ndarray]:
    """(M2,) chi2 and depth of every object-point observation (eq. 2)."""
    T_c_o = est.T_c_w[problem.obj_frames] @ est.T_w_o
    return chi2_depth(T_c_o, problem.oobs_f, est.X_o, problem.oobs_pt, problem.oobs_meas, problem.oobs_inv_sigma2,
                      camera, _disparity_weight(cfg))


def _total_cost(problem: ObjectBAProblem, est: _Estimate, st: _ObjectStructure, camera: StereoCamera,
                cfg: OptimConfig, c2: np.ndarray, c2_o: np.ndarray | None = None) -> float:
    """Summed Huber cost of eq. (6) at `est`: reprojection (chi2 thresholds as deltas), eq. (3), eq. (4).
    `c2` / `c2_o`: chi2 of the static / object-point observations at `est` (None: computed here)."""
    ocfg = cfg.objects
    cost = huber_cost(c2, chi2_thresholds(problem.meas, cfg.chi2_mono, cfg.chi2_stereo)).sum()
    if not problem.optimize_objects:
        return float(cost)
    if c2_o is None:
        c2_o, _ = _object_chi2_depth(problem, est, camera, cfg)
    cost += huber_cost(c2_o, chi2_thresholds(problem.oobs_meas, cfg.chi2_mono, cfg.chi2_stereo))[st.use].sum()
    a, b, dt = st.pair_a, st.pair_b, st.pair_dt
    r = (est.velocity[b] - est.velocity[a]) / np.repeat([ocfg.sigma_linear_acc * dt, ocfg.sigma_angular_acc * dt], 3,
                                                        axis=0).T
    cost += huber_cost(np.einsum("ij,ij->i", r, r), ocfg.chi2_velocity).sum()
    M, _, _ = motion_affine(est.T_w_o[a, :3, :3], est.T_w_o[a, :3, 3], est.T_w_o[b, :3, :3], est.T_w_o[b, :3, 3],
                            est.velocity[a], dt)
    pair_obj = problem.obj_id[a]
    for k in np.unique(pair_obj).tolist():
        mine = pair_obj == k
        cost += motion_cost(M[mine], ocfg.sigma_motion_xyz * dt[mine], est.X_o[st.points & (problem.pt_obj == k)],
                            ocfg.chi2_motion)
    return float(cost)


def _check(problem: ObjectBAProblem) -> None:
    """Shapes, index ranges, one observation per object and keyframe, consistent point ownership."""
    K, F, P2, M2 = len(problem.T_c_w), len(problem.obj_frames), len(problem.X_o), len(problem.oobs_f)
    static_ok = (problem.T_c_w.shape == (K, 4, 4) and problem.fixed.shape == (K,)
                       and problem.X_w.shape[1:] == (3,) and problem.obs_kf.shape == problem.obs_pt.shape
                       and problem.meas.shape == (len(problem.obs_kf), 3)
                       and problem.inv_sigma2.shape == (len(problem.obs_kf),))
    shapes_ok = static_ok and K > 0 and (
        problem.obj_id.shape == (F,) and problem.T_w_o.shape == (F, 4, 4) and problem.v_o.shape == (F, 3)
        and problem.w_o.shape == (F, 3) and problem.timestamps.shape == (K,) and problem.X_o.shape == (P2, 3)
        and problem.pt_obj.shape == (P2,) and problem.oobs_pt.shape == (M2,) and problem.oobs_meas.shape == (M2, 3)
        and problem.oobs_inv_sigma2.shape == (M2,)
        and (problem.obj_measured is None or np.shape(problem.obj_measured) == (F,)))
    if not shapes_ok:
        raise InputError("object_bundle_adjustment: expected T_c_w (K,4,4), fixed (K,), timestamps (K,), X_w (P,3), "
                         "obs_kf/obs_pt (M,), meas (M,3), inv_sigma2 (M,), obj_frames/obj_id (F,), T_w_o (F,4,4), "
                         "v_o/w_o (F,3), X_o (P2,3), pt_obj (P2,), oobs_f/oobs_pt (M2,), oobs_meas (M2,3), "
                         "oobs_inv_sigma2 (M2,), obj_measured (F,) or None, with K >= 1")
    P = len(problem.X_w)
    for name, idx, n in (("obs_kf", problem.obs_kf, K), ("obs_pt", problem.obs_pt, P),
                         ("obj_frames", problem.obj_frames, K), ("oobs_f", problem.oobs_f, F),
                         ("oobs_pt", problem.oobs_pt, P2)):
        if len(idx) and (idx.min() < 0 or idx.max() >= n):
            raise InputError(f"object_bundle_adjustment: {name} must index [0, {n})")
    if len(np.unique(problem.obj_id * K + problem.obj_frames)) != F:
        raise InputError("object_bundle_adjustment: at most one observation per object and keyframe "
                         "(obj_id, obj_frames)")
    if np.any(problem.pt_obj[problem.oobs_pt] != problem.obj_id[problem.oobs_f]):
        raise InputError("object_bundle_adjustment: oobs_pt must be points of the object of oobs_f (pt_obj == obj_id)")
    arrays = (problem.T_c_w, problem.X_w, problem.meas, problem.T_w_o, problem.v_o, problem.w_o, problem.X_o,
              problem.oobs_meas, problem.timestamps)
    if not (all(np.all(np.isfinite(a)) for a in arrays) and np.all(problem.inv_sigma2 > 0)
            and np.all(problem.oobs_inv_sigma2 > 0)):
        raise InputError("object_bundle_adjustment: poses, points, velocities, times and measurements must be "
                         "finite, inv_sigma2 > 0")
    if len(np.unique(problem.timestamps)) != K:
        raise InputError("object_bundle_adjustment: the keyframe timestamps must be distinct")
