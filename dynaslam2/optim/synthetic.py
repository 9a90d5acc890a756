"""Synthetic stereo problems with known ground truth, for the optimizer tests and benchmarks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse, se3_exp, transform


def kitti_like_camera() -> StereoCamera:
    """KITTI odometry 00-02 left camera and stereo baseline."""
    return StereoCamera(718.856, 718.856, 607.1928, 185.2157, 0.5372, 1241, 376)


@dataclass
class SyntheticObservations:
    """Noisy measurements of known points; `outlier` marks gross mismatches."""

    meas: np.ndarray
    inv_sigma2: np.ndarray
    outlier: np.ndarray


def perturb_poses(rng: np.random.Generator, T: np.ndarray, sigma_t: float, sigma_r: float) -> np.ndarray:
    """Left-multiply (..., 4, 4) poses by random twists (sigma_t metres, sigma_r radians)."""
    shape = T.shape[:-2] + (3,)
    xi = np.concatenate([rng.normal(0, sigma_t, shape), rng.normal(0, sigma_r, shape)], -1)
    return se3_exp(xi) @ T


def sample_points_in_view(
    rng: np.random.Generator, camera: StereoCamera, T_c_w: np.ndarray, n: int, depth_range: tuple[float, float]
) -> np.ndarray:
    """(n, 3) world points that project inside the image of camera `T_c_w` at the given depths."""
    uv = rng.uniform([20, 20], [camera.width - 20, camera.height - 20], (n, 2))
    X_c = camera.backproject(uv, rng.uniform(*depth_range, n))
    return transform(inverse(T_c_w), X_c)


def points_first_seen(
    rng: np.random.Generator, camera: StereoCamera, T_c_w: np.ndarray, n_points: int, depth_range
) -> tuple[np.ndarray, np.ndarray]:
    """`n_points` world points, each drawn in the view of a random keyframe: (first keyframe (n,), X_w (n, 3))."""
    first = rng.integers(0, len(T_c_w), n_points)
    X_w = np.empty((n_points, 3))
    for kf in range(len(T_c_w)):
        sel = first == kf
        X_w[sel] = sample_points_in_view(rng, camera, T_c_w[kf], int(sel.sum()), depth_range)
    return first, X_w


def observe(
    rng: np.random.Generator,
    camera: StereoCamera,
    X_c: np.ndarray,
    stereo: np.ndarray,
    outlier_fraction: float = 0.0,
    n_levels: int = 8,
    scale_factor: float = 1.2,
    noise_scale: float = 1.0,
    disparity_weight: float | None = None,
) -> SyntheticObservations:
    """Measure camera-frame points `[u, v, u_right]` with Gaussian pixel noise of sigma
    `noise_scale * scale_factor**level` (the level drawn as ORB's per-level feature counts), independent
    on each coordinate, or with `disparity_weight` k: u_right = u - disparity, u's noise shared and the
    disparity's sigma / k (a stereo match's sub-pixel disparity); u_right=-1: mono."""
    n = len(X_c)
    level_p = scale_factor ** (-2.0 * np.arange(n_levels))
    level = rng.choice(n_levels, n, p=level_p / level_p.sum())
    sigma = scale_factor**level
    noise = rng.normal(0, noise_scale, (n, 3)) * sigma[:, None]
    if disparity_weight is not None:
        noise[:, 2] = noise[:, 0] - noise[:, 2] / disparity_weight
    meas = camera.project_stereo(X_c) + noise
    outlier = rng.random(n) < outlier_fraction
    n_out = int(outlier.sum())
    bad = rng.uniform(25.0, 60.0, (n_out, 2)) * rng.choice([-1.0, 1.0], (n_out, 2))
    meas[outlier, :2] += bad
    meas[outlier, 2] += bad[:, 0]
    meas[~stereo, 2] = -1.0
    return SyntheticObservations(meas, scale_factor ** (-2.0 * level), outlier)


@dataclass
class SyntheticWindow:
    """A local-BA window: ground truth, perturbed initial values and observations."""

    T_c_w_true: np.ndarray
    X_w_true: np.ndarray
    T_c_w_init: np.ndarray
    X_w_init: np.ndarray
    fixed: np.ndarray
    obs_kf: np.ndarray
    obs_pt: np.ndarray
    obs: SyntheticObservations


def make_window(
    rng: np.random.Generator,
    camera: StereoCamera,
    n_keyframes: int = 15,
    n_fixed: int = 5,
    n_points: int = 3000,
    track_length: int = 5,
    outlier_fraction: float = 0.0,
    pose_sigma: tuple[float, float] = (0.05, 0.005),
    point_sigma: float = 0.05,
    th_depth: float = 40.0,
    depth_range: tuple[float, float] = (4.0, 45.0),
    noise_scale: float = 1.0,
) -> SyntheticWindow:
    """A car driving forward 1 m per keyframe with gentle yaw; points seen by up to `track_length`
    consecutive keyframes; observations stereo when closer than `th_depth` baselines, else mono.
    The first `n_fixed` keyframes are fixed (and left unperturbed)."""
    k = np.arange(n_keyframes)
    twist = np.zeros((n_keyframes, 6))
    twist[:, 2] = k * 1.0
    twist[:, 4] = 0.02 * np.sin(k / 3.0)
    T_w_c = se3_exp(twist)
    T_c_w = inverse(T_w_c)
    first, X_w = points_first_seen(rng, camera, T_c_w, n_points, depth_range)
    obs_pt = np.repeat(np.arange(n_points), track_length)
    obs_kf = np.repeat(first, track_length) + np.tile(np.arange(track_length), n_points)
    keep = obs_kf < n_keyframes
    obs_pt, obs_kf = obs_pt[keep], obs_kf[keep]
    X_c = np.einsum("mij,mj->mi", T_c_w[obs_kf, :3, :3], X_w[obs_pt]) + T_c_w[obs_kf, :3, 3]
    visible = X_c[:, 2] > 0.5
    visible[visible] = camera.in_image(camera.project(X_c[visible]))
    obs_pt, obs_kf, X_c = obs_pt[visible], obs_kf[visible], X_c[visible]
    obs = observe(rng, camera, X_c, X_c[:, 2] < th_depth * camera.baseline, outlier_fraction,
                  noise_scale=noise_scale)
    fixed = k < n_fixed
    T_init = T_c_w.copy()
    T_init[~fixed] = perturb_poses(rng, T_c_w[~fixed], *pose_sigma)
    X_init = X_w + rng.normal(0, point_sigma, X_w.shape)
    return SyntheticWindow(T_c_w, X_w, T_init, X_init, fixed, obs_kf, obs_pt, obs)
