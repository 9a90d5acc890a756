"""Object motion model (paper eq. 5) and object pose-only optimization (paper III-B).

Velocity convention (paper III-A: "all in object coordinates"): the linear velocity `v_o` and the
angular velocity `w_o` of an object observation are expressed in the object frame at that time;
over `dt` the object moves by `dT = [Exp(w_o dt), v_o dt; 0 1]` applied on the right,
`T_w_o(t + dt) = T_w_o(t) @ dT` (eq. 5). `v_o dt` is the displacement of the object-frame origin
in the object frame at `t` (not the translation of se3_exp of a twist).
"""

from __future__ import annotations

import numpy as np

from dynaslam2.config import OptimConfig
from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse, make_pose, so3_exp, so3_log
from dynaslam2.optim.pose_only import optimize_pose


def motion_increment(v_o: np.ndarray, w_o: np.ndarray, dt: np.ndarray | float) -> np.ndarray:
    """(..., 4, 4) eq. (5): `[Exp(w_o dt), v_o dt; 0 1]` for (..., 3) velocities and (...) or scalar dt."""
    dt = np.asarray(dt, dtype=float)[..., None]
    return make_pose(so3_exp(np.asarray(w_o, dtype=float) * dt), np.asarray(v_o, dtype=float) * dt)


def predict_object_pose(T_w_o: np.ndarray, v_o: np.ndarray, w_o: np.ndarray, dt: float) -> np.ndarray:
    """Constant-velocity prediction (eq. 5): `T_w_o @ motion_increment(v_o, w_o, dt)`."""
    return np.asarray(T_w_o, dtype=float) @ motion_increment(v_o, w_o, dt)


def object_velocity(T_w_o_prev: np.ndarray, T_w_o_next: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(v_o, w_o) that carry `T_w_o_prev` exactly onto `T_w_o_next` in `dt` (inverse of eq. 5)."""
    if not dt > 0:
        raise InputError(f"object_velocity: dt must be > 0, got {dt}")
    dT = inverse(T_w_o_prev) @ T_w_o_next
    return dT[..., :3, 3] / dt, so3_log(dT[..., :3, :3]) / dt


def optimize_object_pose(
    T_c_w: np.ndarray,
    T_w_o_init: np.ndarray,
    X_o: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    camera: StereoCamera,
    cfg: OptimConfig,
    disparity_weight: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Refine an object pose from its points `X_o` (object frame) seen by a fixed camera `T_c_w`
    (paper III-B); returns (T_w_o (4,4), inliers (N,) bool).

    With the camera fixed, the camera pose in the object frame `T_c_o = T_c_w T_w_o` is the only
    unknown: this is exactly camera pose-only optimization on constant points (`optimize_pose`,
    same Huber / chi2 rounds and thresholds, `disparity_weight` as there), mapped back by
    `T_w_o = T_c_w^-1 T_c_o`.
    """
    T_c_w = np.asarray(T_c_w, dtype=float)
    T_w_o_init = np.asarray(T_w_o_init, dtype=float)
    if T_c_w.shape != (4, 4) or T_w_o_init.shape != (4, 4):
        raise InputError(f"optimize_object_pose: T_c_w and T_w_o_init must be (4, 4), got {T_c_w.shape}, "
                         f"{T_w_o_init.shape}")
    T_c_o, inliers = optimize_pose(T_c_w @ T_w_o_init, X_o, meas, inv_sigma2, camera, cfg, disparity_weight)
    return inverse(T_c_w) @ T_c_o, inliers
