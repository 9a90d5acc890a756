"""Levenberg-Marquardt on the static reprojection terms (paper eq. 1) in numpy, points eliminated.

Each iteration linearizes every observation at once (`static_schur.linearize_static`: closed-form stereo
Jacobians, Huber weights as gtsam's Robust model), eliminates the points from the damped normal
equations (`reduce_static`: the reduced camera system, (6C, 6C) dense), solves it by Cholesky and
back-substitutes the points: the same damped step as gtsam's LevenbergMarquardtOptimizer on the same
factors with lambda * I damping (whitened units), points eliminated first (optim.ordering "SCHUR"). The
schedule is gtsam's as well: a step is taken when the cost falls by more than 1e-3 of the linear
model's predicted decrease, otherwise lambda grows and the step is solved again; lambda then shrinks by
Nielsen's rule (or a fixed factor 10), and LM stops after `max_iterations` steps or when the cost falls
by less than `relative_error_tol` of itself or by less than 1e-5. The predicted decrease is the model's
own (cost of the weighted residuals minus the model's cost at the step), as in Ceres.

A stated replacement of gtsam for the static local BA (optim.local_ba_solver; gtsam's stays as the
reference, tests/test_schur_lm.py: the same steps to 1e-9 m). Replaying the 59 static local BA windows of
sim traffic s0 640x480 (150 frames; median 3311 points, 18.4k observations; `python
benchmarks/bench_ba.py --slam-windows SEQ --slam-frames 150 --repeats 3 --compare optim.local_ba_solver=gtsam`,
OPENBLAS_NUM_THREADS=1; with OpenBLAS's default threads the process CPU time also counts its spinning
threads): median 46 ms CPU against gtsam's 99 with its factor cache (0.46x; 89 against 194 on a slower
day), the same distance from the converged windows (0.17 cm) and the same cost. KITTI 06 clip, static
mode end to end: local BA 36 against 62 ms per keyframe (wall), the same ATE. Of a call (cProfile on
those windows), the point elimination and the reduced camera system were ~3/5 (scipy's block-sparse
product ~1/3 of that), the linearization and the cost and chi2 evaluations ~1/6 each, before
`reduce_static` factored the point blocks in closed form (faster on the joint windows of the BA with
objects, about as fast on these).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import se3_exp
from dynaslam2.optim.reprojection import chi2_depth, huber_cost, is_stereo
from dynaslam2.optim.static_schur import linearize_static, reduce_static

LAMBDA_FACTOR = 10.0  # gtsam's LevenbergMarquardtParams defaults (Nielsen's factor starts there, restarts at 2)
NIELSEN_FACTOR = 2.0
LAMBDA_UPPER_BOUND = 1e5
MIN_MODEL_FIDELITY = 1e-3
ABSOLUTE_ERROR_TOL = 1e-5


def robust_cost(T_c_w: np.ndarray, X_w: np.ndarray, obs_kf: np.ndarray, obs_pt: np.ndarray, meas: np.ndarray,
                inv_sigma2: np.ndarray, camera: StereoCamera, min_depth: float,
                delta2: np.ndarray | None) -> float:
    """Summed Huber cost (`delta2` per observation; None: 1/2 chi2) of the observations. One closer than
    `min_depth` costs as a residual of 2 fx on each coordinate, as gtsam's stereo and projection factors
    return with their cheirality exception off."""
    c2, depth = chi2_depth(T_c_w, obs_kf, X_w, obs_pt, meas, inv_sigma2, camera)
    c2 = np.where(depth > min_depth, c2, np.where(is_stereo(meas), 3.0, 2.0) * (2.0 * camera.fx) ** 2 * inv_sigma2)
    return float(0.5 * c2.sum() if delta2 is None else huber_cost(c2, delta2).sum())


def schur_levenberg_marquardt(T_c_w: np.ndarray, free: np.ndarray, X_w: np.ndarray, obs_kf: np.ndarray,
                              obs_pt: np.ndarray, meas: np.ndarray, inv_sigma2: np.ndarray, camera: StereoCamera,
                              min_depth: float, delta2: np.ndarray | None, max_iterations: int,
                              lambda_initial: float, relative_error_tol: float,
                              fixed_lambda_factor: bool) -> tuple[np.ndarray, np.ndarray, int]:
    """Minimize the static terms over the `free` cameras (K,) and the observed points (module docstring).
    Returns (T_c_w, X_w, iterations): new arrays, the fixed cameras and the unobserved points unchanged.
    The caller holds the gauge (at least one observed camera not free)."""
    T_c_w, X_w = T_c_w.copy(), X_w.copy()
    args = (obs_kf, obs_pt, meas, inv_sigma2, camera, min_depth, delta2)
    cost = robust_cost(T_c_w, X_w, *args)
    lam, factor = lambda_initial, LAMBDA_FACTOR
    iterations = 0
    while iterations < max_iterations:
        lin = linearize_static(T_c_w, X_w, *args)
        while True:  # gtsam's LM iteration: solve for this lambda, accept or raise lambda and solve again
            step = _damped_step(lin, free, lam)
            if step is not None:
                d_cams, d_points, points = step
                predicted = lin.cost - lin.model_cost(d_cams, _scatter(d_points, points, len(X_w)))
                if predicted >= 0.0:
                    T_new = _retract(T_c_w, d_cams)
                    X_new = X_w.copy()
                    X_new[points] += d_points
                    new_cost = robust_cost(T_new, X_new, *args)
                    fidelity = (cost - new_cost) / predicted if predicted > 0.0 else 1.0
                    if fidelity > MIN_MODEL_FIDELITY:
                        break
            if fixed_lambda_factor:
                lam *= LAMBDA_FACTOR
            else:
                lam, factor = lam * factor, factor * 2.0
            if lam >= LAMBDA_UPPER_BOUND:  # gtsam gives up: no step decreases the cost
                return T_c_w, X_w, iterations
        iterations += 1
        if fixed_lambda_factor:
            lam /= LAMBDA_FACTOR
        else:
            lam, factor = lam * max(1.0 / 3.0, 1.0 - (2.0 * fidelity - 1.0) ** 3), NIELSEN_FACTOR
        decrease = cost - new_cost
        T_c_w, X_w, cost = T_new, X_new, new_cost
        if decrease <= ABSOLUTE_ERROR_TOL or decrease <= relative_error_tol * (cost + decrease):
            break
    return T_c_w, X_w, iterations


def _damped_step(lin, free: np.ndarray, lam: float):
    """(K, 6) camera and (P', 3) point increments of the system damped by lam * I, and the points' indices;
    None when the reduced camera system is not positive definite."""
    try:
        schur = reduce_static(lin, free, lam)
    except np.linalg.LinAlgError:  # a point block singular at this damping
        return None
    n = len(schur.s)
    d_cams = np.zeros((len(free), 6))
    if n:
        try:
            factor = cho_factor(schur.S + lam * np.eye(n))
        except np.linalg.LinAlgError:
            return None
        d_cams[schur.cams] = -cho_solve(factor, schur.s).reshape(-1, 6)
    return d_cams, schur.point_steps(d_cams[schur.cams]), schur.points


def _scatter(d_points: np.ndarray, points: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((n, 3))
    out[points] = d_points
    return out


def _retract(T_c_w: np.ndarray, d_cams: np.ndarray) -> np.ndarray:
    """T_w_c Exp(omega, nu) for (K, 6) increments (omega, nu), as camera-from-world poses."""
    T_delta_inv = se3_exp(-np.concatenate([d_cams[:, 3:], d_cams[:, :3]], axis=1))  # Exp(xi)^-1 = Exp(-xi)
    return T_delta_inv @ T_c_w
