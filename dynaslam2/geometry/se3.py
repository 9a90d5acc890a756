"""SO(3) / SE(3) in numpy: exp/log, inverse, compose, transform; vectorized over leading axes.

Poses are 4x4 homogeneous matrices `T_a_b` with `x_a = T_a_b @ x_b`. Tangent vectors are
`xi = (rho, phi)`: translation part first, rotation part second (gtsam's Pose3 order is
(phi, rho); convert at the gtsam boundary only).
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-10


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices of (..., 3) vectors -> (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -w[..., 2], w[..., 1]
    out[..., 1, 0], out[..., 1, 2] = w[..., 2], -w[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -w[..., 1], w[..., 0]
    return out


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: (..., 3) rotation vectors -> (..., 3, 3) rotation matrices (paper eq. 5's Exp)."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = hat(w)
    small = theta < 1e-8
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    return np.eye(3) + a * K + b * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 3) rotation vectors, stable near 0 and pi."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    cos = np.clip((tr - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = np.sin(theta)
    small = theta < 1e-6
    scale = np.where(small, 0.5 + theta**2 / 12.0, theta / (2.0 * np.where(small, 1.0, sin)))
    w = v * scale[..., None]
    near_pi = theta > np.pi - 1e-4
    if np.any(near_pi):
        # Near pi the antisymmetric part vanishes: take the axis from the symmetric part.
        Rp = R[near_pi]
        B = ((Rp + np.swapaxes(Rp, -1, -2)) / 2.0 + np.eye(3)) / 2.0  # symmetric part ~ a a^T
        diag = np.clip(np.diagonal(B, axis1=-2, axis2=-1), 0.0, None)
        axis = np.sqrt(diag)
        k = np.argmax(diag, axis=-1)
        idx = np.arange(len(Rp))
        col = B[idx, :, k] / np.maximum(axis[idx, k], _EPS)[:, None]
        sign = np.sign(np.einsum("ni,ni->n", col, v[near_pi]))
        sign[sign == 0] = 1.0
        w[near_pi] = col / np.linalg.norm(col, axis=-1, keepdims=True) * (theta[near_pi] * sign)[:, None]
    return w


def so3_left_jacobian(w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) left Jacobian of SO(3) at (..., 3) rotation vectors: Exp(w + d) ~ Exp(J_l d) Exp(w)
    (series below 1e-4 rad, where the closed form loses digits)."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = hat(w)
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (t - np.sin(t)) / t**3)
    return np.eye(3) + a * K + b * (K @ K)


def so3_right_jacobian(w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) right Jacobian: Exp(w + d) ~ Exp(w) Exp(J_r d), J_r(w) = J_l(-w) (gtsam's
    Rot3.ExpmapDerivative)."""
    return so3_left_jacobian(-np.asarray(w))


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """(..., 6) twists (rho, phi) -> (..., 4, 4) poses."""
    xi = np.asarray(xi, dtype=float)
    rho, phi = xi[..., :3], xi[..., 3:]
    T = np.zeros(xi.shape[:-1] + (4, 4))
    T[..., :3, :3] = so3_exp(phi)
    T[..., :3, 3] = np.einsum("...ij,...j->...i", so3_left_jacobian(phi), rho)
    T[..., 3, 3] = 1.0
    return T


def se3_log(T: np.ndarray) -> np.ndarray:
    """(..., 4, 4) poses -> (..., 6) twists (rho, phi)."""
    T = np.asarray(T, dtype=float)
    phi = so3_log(T[..., :3, :3])
    rho = np.linalg.solve(so3_left_jacobian(phi), T[..., :3, 3][..., None])[..., 0]
    return np.concatenate([rho, phi], -1)


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stack (..., 3, 3) rotations and (..., 3) translations into (..., 4, 4) poses."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    T = np.zeros(np.broadcast_shapes(R.shape[:-2], t.shape[:-1]) + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms, using R^T (exact for rotations)."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_pose(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def transform(T: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points: `T[:3,:3] @ X + T[:3,3]`."""
    X = np.asarray(X, dtype=float)
    return X @ T[:3, :3].T + T[:3, 3]


def yaw_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """Pose with rotation about +z by `yaw` and translation (x, y, z)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return make_pose(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array([x, y, z]))


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians of (..., 3, 3) rotations."""
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))
