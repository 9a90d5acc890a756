"""Vectorized stereo/mono reprojection residuals, Jacobians and chi-square tests (paper eq. (1)).

Observations are `[u, v, u_right]` rows with `u_right < 0` meaning monocular: a stereo observation
has 3 residuals, a monocular one 2 (its third residual is zero).
"""

from __future__ import annotations

import numpy as np

from dynaslam2.geometry.camera import StereoCamera


def is_stereo(meas: np.ndarray) -> np.ndarray:
    """(M,) bool: the observation has a right coordinate."""
    return meas[:, 2] >= 0


def residuals(camera: StereoCamera, X_c: np.ndarray, meas: np.ndarray) -> np.ndarray:
    """(M, 3) predicted minus measured `[u, v, u_right]` of camera-frame points (mono: third = 0)."""
    z = X_c[:, 2]
    z = np.where(np.abs(z) < 1e-12, 1e-12, z)
    u = camera.fx * X_c[:, 0] / z + camera.cx
    v = camera.fy * X_c[:, 1] / z + camera.cy
    e = np.stack([u - meas[:, 0], v - meas[:, 1], u - camera.bf / z - meas[:, 2]], -1)
    e[~is_stereo(meas), 2] = 0.0
    return e


def disparity_residuals(e: np.ndarray, meas: np.ndarray, disparity_weight: np.ndarray | float) -> np.ndarray:
    """(M, 3) residuals `[u, v, disparity x disparity_weight]` (weight per row or one) from the
    `[u, v, u_right]` ones `e`: the disparity residual is e_u - e_u_right (predicted minus measured
    u - u_right); mono rows keep 0."""
    out = e.copy()
    out[:, 2] = np.where(is_stereo(meas), disparity_weight * (e[:, 0] - e[:, 2]), 0.0)
    return out


def chi2(e: np.ndarray, inv_sigma2: np.ndarray) -> np.ndarray:
    """(M,) squared Mahalanobis norms of (M, 3) residuals, isotropic sigma^-2 per observation."""
    return np.einsum("ij,ij->i", e, e) * inv_sigma2


def chi2_depth(T_c_x: np.ndarray, obs_frame: np.ndarray, X: np.ndarray, obs_pt: np.ndarray, meas: np.ndarray,
               inv_sigma2: np.ndarray, camera: StereoCamera,
               disparity_weight: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(M,) chi2 and depth of observations: point `X[obs_pt]` (in frame x: world, or an object's frame)
    seen by the camera `T_c_x[obs_frame]`; residuals `[u, v, u_right]`, or `[u, v, disparity]` with the
    disparity at sigma / `disparity_weight`."""
    T = T_c_x[obs_frame]
    X_c = np.einsum("mij,mj->mi", T[:, :3, :3], X[obs_pt]) + T[:, :3, 3]
    e = residuals(camera, X_c, meas)
    if disparity_weight is not None:
        e = disparity_residuals(e, meas, disparity_weight)
    return chi2(e, inv_sigma2), X_c[:, 2]


def chi2_thresholds(meas: np.ndarray, chi2_mono: float, chi2_stereo: float) -> np.ndarray:
    """(M,) chi-square threshold per observation: 3 dof for stereo, 2 dof for mono."""
    return np.where(is_stereo(meas), chi2_stereo, chi2_mono)


def huber_cost(chi2_values: np.ndarray, delta2: np.ndarray) -> np.ndarray:
    """(M,) Huber cost of whitened squared norms: chi2/2 inside, delta*|r| - delta^2/2 beyond."""
    r = np.sqrt(chi2_values)
    delta = np.sqrt(delta2)
    return np.where(chi2_values <= delta2, 0.5 * chi2_values, delta * r - 0.5 * delta2)
