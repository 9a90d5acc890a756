"""Filters of an object track's state between BAs (not in the paper; `objects.filter`): a constant-velocity Kalman
filter of the object-frame origin (world position, world velocity), a constant-angular-velocity filter of the
rotation (`objects.rotation_filter`), and the validation gate of associations against the position filter. The
state lives in the `ObjectTrack` (`state_mean`, `state_cov`, `rot_cov`)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dynaslam2.classes import VEHICLE_CLASSES
from dynaslam2.config import ObjectsConfig
from dynaslam2.geometry.se3 import so3_exp, so3_log, so3_right_jacobian
from dynaslam2.map.objects import ObjectTrack


def white_acceleration_noise(sigma: float, dt: float) -> np.ndarray:
    """(6, 6) process noise of a constant-velocity state (value, rate), 3 axes each, over `dt` under white
    acceleration of sigma `sigma` (discrete form)."""
    return sigma**2 * np.kron(np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]]), np.eye(3))


def capped_angular_velocity(w_o: np.ndarray, cfg: ObjectsConfig) -> np.ndarray:
    """`w_o` scaled down to max_angular_speed (axis kept) when faster."""
    speed = np.linalg.norm(w_o)
    return w_o * (cfg.max_angular_speed / speed) if speed > cfg.max_angular_speed else w_o


def predict_state(track: ObjectTrack, dt: float, cfg: ObjectsConfig) -> tuple[np.ndarray, np.ndarray]:
    """(mean (6,), covariance (6, 6)) of the track's position filter predicted `dt` ahead; with
    objects.vehicle_turn a vehicle's velocity turns at its rotation's (capped) angular velocity, a coordinated turn
    of known rate (the position moves along the velocity turned half way)."""
    F = np.eye(6)
    F[:3, 3:] = dt * np.eye(3)
    if cfg.vehicle_turn and track.cls in VEHICLE_CLASSES and track.observations:
        last = track.last
        w_w = last.T_w_o[:3, :3] @ capped_angular_velocity(last.w_o, cfg)
        F[:3, 3:] = dt * so3_exp(0.5 * dt * w_w)
        F[3:, 3:] = so3_exp(dt * w_w)
    return F @ track.state_mean, F @ track.state_cov @ F.T + white_acceleration_noise(cfg.accel_sigma, dt)


def initial_speed_sigma(cls: str, cfg: ObjectsConfig) -> float:
    """The velocity prior (m/s per axis) of a new track of class `cls`: pedestrian_initial_speed_sigma for a
    pedestrian, initial_speed_sigma for any other class."""
    return cfg.pedestrian_initial_speed_sigma if cls == "pedestrian" else cfg.initial_speed_sigma


def position_noise(info: np.ndarray, cfg: ObjectsConfig) -> np.ndarray:
    """(3, 3) covariance of a pose-only object position of information `info`, with the floor."""
    I3 = np.eye(3)
    return np.linalg.inv(info + 1e-9 * I3) + cfg.position_floor_m**2 * I3


def filter_position(track: ObjectTrack, dt: float, p_meas: np.ndarray, info: np.ndarray | None,
                    cfg: ObjectsConfig) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity Kalman filter of the object-frame origin (white acceleration of sigma `accel_sigma`):
    predict over `dt`, update with the pose-only position of information `info` (None: prediction only). Returns
    the filtered (position, world velocity)."""
    I3 = np.eye(3)
    if info is not None:
        R = position_noise(info, cfg)
    if track.state_mean is None:
        track.state_mean = np.r_[p_meas, np.zeros(3)]
        R0 = R if info is not None else cfg.position_floor_m**2 * I3
        track.state_cov = np.block([[R0, np.zeros((3, 3))],
                                    [np.zeros((3, 3)), initial_speed_sigma(track.cls, cfg)**2 * I3]])
        return track.state_mean[:3].copy(), track.state_mean[3:].copy()
    m, P = predict_state(track, dt, cfg)
    if info is not None:
        K = P[:, :3] @ np.linalg.inv(P[:3, :3] + R)
        m = m + K @ (p_meas - m[:3])
        P = P - K @ P[:3, :]
    track.state_mean, track.state_cov = m, 0.5 * (P + P.T)
    return m[:3].copy(), m[3:].copy()


def predicted_rotation(track: ObjectTrack, dt: float, cfg: ObjectsConfig) -> np.ndarray:
    """The rotation filter's prediction `dt` after the track's last observation: its rotation turned at its capped
    w_o."""
    last = track.last
    return last.T_w_o[:3, :3] @ so3_exp(capped_angular_velocity(last.w_o, cfg) * dt)


def filter_rotation(track: ObjectTrack, dt: float, R_meas: np.ndarray, rot_cov: np.ndarray | None,
                    cfg: ObjectsConfig) -> tuple[np.ndarray, np.ndarray]:
    """Constant-angular-velocity filter of the object rotation (error state d: R = R_mean Exp(d), object frame;
    white angular acceleration of sigma `angular_accel_sigma`), mean (the last observation's rotation and w_o, so
    that a BA's write-back restarts it) and covariance `track.rot_cov`: predict over `dt` with the capped w_o (the
    tracker's constant-velocity turn when the track's velocity is known; the filter's own turn rate otherwise),
    update with the pose-only rotation `R_meas` of covariance `rot_cov` + rotation_floor_rad^2. `rot_cov` None:
    `R_meas` is the track's prediction, kept with the last w_o (the covariance is predicted). Returns (rotation,
    w_o)."""
    I3 = np.eye(3)
    R_noise = None if rot_cov is None else rot_cov + cfg.rotation_floor_rad**2 * I3
    if track.rot_cov is None:  # the track's first observation
        R0 = R_noise if R_noise is not None else cfg.rotation_floor_rad**2 * I3
        track.rot_cov = np.block([[R0, np.zeros((3, 3))],
                                  [np.zeros((3, 3)), cfg.initial_angular_speed_sigma**2 * I3]])
        return R_meas, np.zeros(3)
    last = track.last
    w = capped_angular_velocity(last.w_o, cfg)
    F = np.block([[so3_exp(-w * dt), so3_right_jacobian(w * dt) * dt], [np.zeros((3, 3)), I3]])
    P = F @ track.rot_cov @ F.T + white_acceleration_noise(cfg.angular_accel_sigma, dt)
    if R_noise is None:
        track.rot_cov = 0.5 * (P + P.T)
        return R_meas, last.w_o.copy()
    R = predicted_rotation(track, dt, cfg)
    K = P[:, :3] @ np.linalg.inv(P[:3, :3] + R_noise)
    d = K @ so3_log(R.T @ R_meas)
    P = P - K @ P[:3, :]
    track.rot_cov = 0.5 * (P + P.T)
    return R @ so3_exp(d[:3]), w + d[3:]


def gated(track: ObjectTrack, dt: float, p_w: np.ndarray, information: Callable[[], np.ndarray],
          cfg: ObjectsConfig, nis: float | None = None) -> bool:
    """Validation gate (with the filter and a finite threshold `nis`, gate_nis by default): True when the filter's
    prediction `dt` ahead cannot explain position `p_w` of (3, 3) information `information()` (an association
    outlier)."""
    nis = cfg.gate_nis if nis is None else nis
    if not (cfg.filter and track.state_mean is not None and np.isfinite(nis)):
        return False
    m, P = predict_state(track, dt, cfg)
    y = p_w - m[:3]
    return float(y @ np.linalg.solve(P[:3, :3] + position_noise(information(), cfg), y)) > nis
