"""Trajectory metrics with evo's definitions: Umeyama alignment, ATE (APE) and RPE.

Estimated and ground-truth trajectories are (N, 4, 4) arrays of `T_w_c`, frame i of one matching
frame i of the other. Every function is vectorized over the frames.
"""

from __future__ import annotations

import numpy as np

from dynaslam2.geometry.se3 import inverse


def umeyama_alignment(X: np.ndarray, Y: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares `(R, t, s)` with `Y ~ s * R @ X + t` for (N, 3) point sets (Umeyama 1991, eqs. 34-43).

    Same solution as evo's `umeyama_alignment`. Where evo raises on a rank-deficient covariance
    (e.g. a straight-line trajectory), this returns one of the equally optimal solutions: the
    alignment residual, hence the ATE, is the same for all of them.
    """
    X = np.asarray(X, dtype=float)
    Y = np.asarray(Y, dtype=float)
    if X.shape != Y.shape or X.ndim != 2 or X.shape[1] != 3 or len(X) == 0:
        raise ValueError(f"umeyama_alignment: expected two (N, 3) arrays with N > 0, got {X.shape} and {Y.shape}")
    mean_x, mean_y = X.mean(axis=0), Y.mean(axis=0)
    Xc, Yc = X - mean_x, Y - mean_y
    cov_yx = Yc.T @ Xc / len(X)
    U, d, Vt = np.linalg.svd(cov_yx)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    sigma_x = np.sum(Xc**2) / len(X)
    s = float(np.trace(np.diag(d) @ S) / sigma_x) if with_scale and sigma_x > 0.0 else 1.0
    t = mean_y - s * (R @ mean_x)
    return R, t, s


def rotation_angle_rad(R: np.ndarray) -> np.ndarray:
    """Angle of (..., 3, 3) rotations, accurate near 0 and pi (atan2 of the antisymmetric and trace parts).

    Matrices are first projected onto the nearest rotation (polar decomposition), as scipy's
    `Rotation.from_matrix` (used by evo) does: rotations read from text files are orthonormal
    only to ~1e-7, which would otherwise shift the angle by ~1e-8 rad.
    """
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = 0.5 * np.linalg.norm(v, axis=-1)
    cos = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(sin, cos)


def _check_pair(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T_est = np.asarray(T_est, dtype=float)
    T_gt = np.asarray(T_gt, dtype=float)
    if T_est.shape != T_gt.shape or T_est.ndim != 3 or T_est.shape[1:] != (4, 4) or len(T_est) == 0:
        raise ValueError(f"expected two (N, 4, 4) trajectories with the same N > 0, got {T_est.shape} and {T_gt.shape}")
    return T_est, T_gt


def ate(T_w_c_est: np.ndarray, T_w_c_gt: np.ndarray, align: str = "se3") -> dict:
    """Absolute trajectory error of the positions (evo's APE, translation part), in metres.

    align="se3": estimated positions are first mapped onto GT by the SE(3) Umeyama alignment
    (evo `--align`); align="none": compared as they are. Returns rmse_m, mean_m, median_m, max_m,
    the per-frame errors_m and the alignment T_gt_est (4, 4).
    """
    T_est, T_gt = _check_pair(T_w_c_est, T_w_c_gt)
    p_est, p_gt = T_est[:, :3, 3], T_gt[:, :3, 3]
    T_gt_est = np.eye(4)
    if align == "se3":
        R, t, _ = umeyama_alignment(p_est, p_gt, with_scale=False)
        T_gt_est[:3, :3], T_gt_est[:3, 3] = R, t
    elif align != "none":
        raise ValueError(f"ate: align must be 'se3' or 'none', got {align!r}")
    errors = np.linalg.norm(p_est @ T_gt_est[:3, :3].T + T_gt_est[:3, 3] - p_gt, axis=1)
    return {
        "rmse_m": float(np.sqrt(np.mean(errors**2))),
        "mean_m": float(np.mean(errors)),
        "median_m": float(np.median(errors)),
        "max_m": float(np.max(errors)),
        "errors_m": errors,
        "T_gt_est": T_gt_est,
    }


def rpe(T_w_c_est: np.ndarray, T_w_c_gt: np.ndarray, delta: int = 1) -> dict:
    """Relative pose error over frame pairs (i, i+delta), evo's RPE with `delta_unit=frames`.

    Pairs are evo's consecutive ones: i = 0, delta, 2*delta, ... For each pair with GT poses Q and
    estimates P: E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j); translation error |t(E)| in metres, rotation error
    the angle of R(E) in degrees. Returns t_rmse_m, t_mean_m, r_rmse_deg, r_mean_deg, pairs and the
    per-pair t_errors_m, r_errors_deg (rmse and mean are 0 with no pair).
    """
    T_est, T_gt = _check_pair(T_w_c_est, T_w_c_gt)
    if int(delta) != delta or delta < 1:
        raise ValueError(f"rpe: delta must be a positive integer number of frames, got {delta!r}")
    ids = np.arange(0, len(T_est), int(delta))
    i, j = ids[:-1], ids[1:]
    Q_rel = inverse(T_gt[i]) @ T_gt[j]
    P_rel = inverse(T_est[i]) @ T_est[j]
    E = inverse(Q_rel) @ P_rel
    t_err = np.linalg.norm(E[:, :3, 3], axis=1)
    r_err = np.degrees(rotation_angle_rad(E[:, :3, :3]))

    def rmse(e: np.ndarray) -> float:
        return float(np.sqrt(np.mean(e**2))) if len(e) else 0.0

    return {
        "t_rmse_m": rmse(t_err),
        "t_mean_m": float(np.mean(t_err)) if len(t_err) else 0.0,
        "r_rmse_deg": rmse(r_err),
        "r_mean_deg": float(np.mean(r_err)) if len(r_err) else 0.0,
        "pairs": int(len(i)),
        "t_errors_m": t_err,
        "r_errors_deg": r_err,
    }
