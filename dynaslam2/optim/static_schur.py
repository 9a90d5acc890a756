"""The static reprojection terms (paper eq. 1) of a BA window reduced to its free cameras (Schur complement).

Linearized at the current estimate (Huber weights of that estimate, as gtsam's Robust model), the static
terms are the quadratic cost + g^T d + 1/2 d^T H d in the camera and point increments; eliminating the
points gives the reduced camera system S = H_cc - H_cp H_pp^-1 H_pc, s = g_c - H_cp H_pp^-1 g_p (points
first, as the SCHUR elimination order), and once the cameras are solved each point moves by
-H_pp^-1 (g_p + H_pc d_c) (back-substitution): without damping, exactly
gtsam's linearization and partial elimination of the same GenericStereoFactor3D / projection factors
(tests/test_static_schur.py), computed in vectorized numpy (closed-form stereo Jacobians, one
block-sparse product for the reduction) instead of building, linearizing and eliminating ~20k factors.

`StaticSchur.factor` puts the reduced system into a gtsam graph as one factor on the free camera
poses (T_w_c, right perturbations), whose error is the quadratic model of the static cost: the BA
with objects (object_ba.py, `optim.objects.static_reduced`) then optimizes cameras and objects with
the static terms linearized once, the points following by back-substitution.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np
import scipy.sparse as sp
from scipy.linalg import solve_triangular

from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.optim.gtsam_utils import pose3_from_matrix
from dynaslam2.optim.reprojection import is_stereo, residuals


@dataclass
class StaticSchur:
    """Reduced camera system of the static terms and what the back-substitution needs."""

    cams: np.ndarray  # (C,) indices of the free cameras, the order of S's 6-blocks
    S: np.ndarray  # (6C, 6C)
    s: np.ndarray  # (6C,)
    points: np.ndarray  # (P',) indices of the points eliminated
    H_pp_inv: np.ndarray  # (P', 3, 3) inverse of the damped point blocks
    g_p: np.ndarray  # (P', 3)
    obs_cam: np.ndarray  # (M',) row in `cams` of each used observation with a free camera
    obs_point: np.ndarray  # (M',) row in `points`
    W: np.ndarray  # (M', 6, 3) H_cp block of each such observation
    cost: float  # 1/2 sum of the whitened, Huber-weighted squared residuals at the linearization point

    @cached_property
    def _square_root(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, b) with A^T A = S, -A^T b = s: A = L^T for S = L L^T (S is positive definite when the fixed
        cameras hold the gauge); else from the eigen-decomposition of S, its null space dropped (eigh
        costs ~100x the Cholesky factorization with multithreaded OpenBLAS on a loaded machine)."""
        S = 0.5 * (self.S + self.S.T)
        try:
            L = np.linalg.cholesky(S)
            return L.T, -solve_triangular(L, self.s, lower=True)
        except np.linalg.LinAlgError:
            lam, V = np.linalg.eigh(S)
            keep = lam > max(lam[-1], 0.0) * 1e-12
            return np.sqrt(lam[keep])[:, None] * V[:, keep].T, -(V[:, keep].T @ self.s) / np.sqrt(lam[keep])

    def factor(self, keys: np.ndarray, T_w_c: np.ndarray) -> gtsam.CustomFactor:
        """One factor on the free cameras' Pose3 keys (`keys[i]` = camera `cams[i]` at `T_w_c[i]`, the
        linearization point): error (A d - b, floor) with A^T A = S, -A^T b = s (`_square_root`) and d =
        Local(T_w_c, pose) per camera; half its squared norm is the quadratic model of the static cost."""
        A, b = self._square_root
        # the model's minimum as a constant row: the factor's error is the whole quadratic model of the
        # static cost, 1/2 |A d - b|^2 + cost - 1/2 |b|^2, so that LM's relative decrease is on the full cost
        floor = np.sqrt(2.0 * max(self.cost - 0.5 * b @ b, 0.0))
        blocks = [np.ascontiguousarray(A[:, 6 * i:6 * i + 6]) for i in range(len(keys))]
        lin = [pose3_from_matrix(T) for T in T_w_c]
        key_list = [int(k) for k in keys]

        def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
            d = np.empty(6 * len(key_list))
            for i, (key, T0) in enumerate(zip(key_list, lin)):
                if H is None:
                    d[6 * i:6 * i + 6] = T0.localCoordinates(values.atPose3(key))
                else:
                    J = np.zeros((6, 6), order="F")
                    d[6 * i:6 * i + 6] = T0.localCoordinates(values.atPose3(key), None, J)
                    H[i] = np.vstack([blocks[i] @ J, np.zeros((1, 6))])
            return np.append(A @ d - b, floor)

        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(b) + 1), key_list, error)

    def point_steps(self, d_cams: np.ndarray) -> np.ndarray:
        """(P', 3) point increments for (C, 6) camera increments: -H_pp^-1 (g_p + sum H_pc d_c)."""
        Wd = np.einsum("mij,mi->mj", self.W, d_cams[self.obs_cam])
        rhs = self.g_p + np.column_stack([np.bincount(self.obs_point, Wd[:, i], len(self.points)) for i in range(3)])
        return -np.einsum("pij,pj->pi", self.H_pp_inv, rhs)


@dataclass
class StaticLinearization:
    """The static terms linearized at one estimate: whitened, Huber-weighted Jacobian rows and residuals
    of every observation (the camera columns (omega, nu) of T_w_c Exp(omega, nu), then the point's X_w)."""

    obs_kf: np.ndarray  # (M,) camera of each observation
    obs_pt: np.ndarray  # (M,) point of each observation
    J: np.ndarray  # (M, 3, 9)
    r: np.ndarray  # (M, 3) whitened, weighted residuals (rows of monocular observations: third 0)
    cost: float  # 1/2 sum |r|^2

    def model_cost(self, d_cams: np.ndarray, d_points: np.ndarray) -> float:
        """1/2 sum |J d + r|^2, the linear model's cost for (K, 6) camera and (P, 3) point increments."""
        d = np.concatenate([d_cams[self.obs_kf], d_points[self.obs_pt]], axis=1)
        e = np.einsum("mij,mj->mi", self.J, d) + self.r
        return 0.5 * float(np.einsum("ij,ij->", e, e))


def linearize_static(T_c_w: np.ndarray, X_w: np.ndarray, obs_kf: np.ndarray, obs_pt: np.ndarray,
                     meas: np.ndarray, inv_sigma2: np.ndarray, camera: StereoCamera, min_depth: float,
                     delta2: np.ndarray | None) -> StaticLinearization:
    """Linearize the given observations at (T_c_w, X_w), with Huber weights as gtsam's Robust model
    (`delta2`: (M,) delta^2 per observation; None: no kernel). Observations closer than `min_depth`
    contribute nothing."""
    R, t = T_c_w[obs_kf, :3, :3], T_c_w[obs_kf, :3, 3]
    X_c = np.einsum("mij,mj->mi", R, X_w[obs_pt]) + t
    r = residuals(camera, X_c, meas)
    x, y, z = X_c.T
    ok = z > min_depth
    inv_z = 1.0 / np.where(ok, z, 1.0)
    w = np.where(ok, inv_sigma2, 0.0)  # information of each observation, times its Huber weight
    if delta2 is not None:
        c2 = np.maximum(np.einsum("ij,ij->i", r, r) * inv_sigma2, 1e-300)
        w = w * np.minimum(1.0, np.sqrt(delta2 / c2))
    # whitened, Huber-weighted Jacobian rows of [u, v, u_right] on (omega, nu) of T_w_c Exp(omega, nu) and
    # on X_w: with d pi / d X_c rows (a, 0, c), (0, b, d), (a, 0, e) (the third zero if monocular), the
    # camera block is [row x [X_c]x, -row] (X_c' = X_c + [X_c]x omega - nu) and the point block row R_c_w
    sw = np.sqrt(w)
    stereo = is_stereo(meas)
    a = sw * camera.fx * inv_z
    b = sw * camera.fy * inv_z
    c = -a * x * inv_z
    d = -b * y * inv_z
    a2 = np.where(stereo, a, 0.0)
    e = np.where(stereo, -sw * (camera.fx * x - camera.bf) * inv_z**2, 0.0)
    J = np.zeros((len(z), 3, 9))
    J[:, 0, 0], J[:, 0, 1], J[:, 0, 2], J[:, 0, 3], J[:, 0, 5] = -c * y, c * x - a * z, a * y, -a, -c
    J[:, 1, 0], J[:, 1, 1], J[:, 1, 2], J[:, 1, 4], J[:, 1, 5] = b * z - d * y, d * x, -b * x, -b, -d
    J[:, 2, 0], J[:, 2, 1], J[:, 2, 2], J[:, 2, 3], J[:, 2, 5] = -e * y, e * x - a2 * z, a2 * y, -a2, -e
    J[:, 0, 6:] = a[:, None] * R[:, 0] + c[:, None] * R[:, 2]
    J[:, 1, 6:] = b[:, None] * R[:, 1] + d[:, None] * R[:, 2]
    J[:, 2, 6:] = a2[:, None] * R[:, 0] + e[:, None] * R[:, 2]
    r = sw[:, None] * r
    return StaticLinearization(obs_kf, obs_pt, J, r, 0.5 * float(np.einsum("ij,ij->", r, r)))


def reduce_static(lin: StaticLinearization, free: np.ndarray, damping: float) -> StaticSchur:
    """Eliminate the points of a linearization, each point's block damped as Levenberg-Marquardt's
    H_pp + damping I (whitened units); damping 0 is the plain Schur complement (every point determined).
    `free`: (K,) bool, the cameras kept as variables (the others are constants)."""
    J, r = lin.J, lin.r
    points, obs_point = np.unique(lin.obs_pt, return_inverse=True)
    n_p = len(points)
    # normal-equation blocks [[H_cc, W], [W^T, H_pp]] and gradient (g_c, g_p): the point ones summed entry
    # by entry (bincount), the camera ones only where the camera is free
    Jp = J[:, :, 6:]
    H_pp = np.empty((n_p, 3, 3))
    for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):
        H_pp[:, i, j] = H_pp[:, j, i] = np.bincount(obs_point, np.einsum("mk,mk->m", Jp[:, :, i], Jp[:, :, j]), n_p)
    g_p = np.column_stack([np.bincount(obs_point, np.einsum("mk,mk->m", Jp[:, :, i], r), n_p) for i in range(3)])
    H_pp_inv = np.linalg.inv(H_pp + damping * np.eye(3))

    K = len(free)
    cams = np.flatnonzero(free)
    C, n = len(cams), 6 * len(cams)
    cam_row = np.full(K, -1, dtype=np.int64)
    cam_row[cams] = np.arange(C)
    on_free = np.flatnonzero(cam_row[lin.obs_kf] >= 0)
    on_free = on_free[np.argsort(lin.obs_kf[on_free], kind="stable")]  # grouped by camera (contiguous rows)
    oc, op = cam_row[lin.obs_kf[on_free]], obs_point[on_free]
    indptr = np.concatenate([[0], np.cumsum(np.bincount(oc, minlength=C))])
    Jc = J[on_free, :, :6]
    W = Jc.transpose(0, 2, 1) @ Jp[on_free]  # (M', 6, 3) H_cp block of each observation
    # each camera's H_cc and g_c - W H_pp^-1 g_p: one product over its stacked rows
    Jc_rows, r_rows = Jc.reshape(-1, 6), r[on_free].ravel()
    Wy = np.einsum("mij,mj->mi", W, np.einsum("pij,pj->pi", H_pp_inv, g_p)[op])
    S = np.zeros((C, 6, C, 6))
    s = np.zeros((C, 6))
    for c in range(C):
        rows = slice(3 * indptr[c], 3 * indptr[c + 1])
        S[c, :, c, :] = Jc_rows[rows].T @ Jc_rows[rows]
        s[c] = Jc_rows[rows].T @ r_rows[rows] - Wy[indptr[c]:indptr[c + 1]].sum(axis=0)
    # reduction sum_p W_p H_pp^-1 W_p^T = U U^T, U = W chol(H_pp^-1): a block-sparse (6C, 3P) matrix whose
    # 6x3 blocks are the observations grouped by camera (scipy's BSR product: ~3x its CSR one)
    U = W @ np.linalg.cholesky(H_pp_inv)[op]
    Us = sp.bsr_matrix((U, op, indptr), shape=(n, 3 * n_p))
    S = S.reshape(n, n) - (Us @ Us.T).toarray()
    return StaticSchur(cams, S, s.ravel(), points, H_pp_inv, g_p, oc, op, W, lin.cost)


def static_schur(T_c_w: np.ndarray, free: np.ndarray, X_w: np.ndarray, obs_kf: np.ndarray, obs_pt: np.ndarray,
                 meas: np.ndarray, inv_sigma2: np.ndarray, camera: StereoCamera, min_depth: float,
                 delta2: np.ndarray | None, damping: float) -> StaticSchur:
    """`linearize_static` then `reduce_static`: the static terms at (T_c_w, X_w) reduced to the free
    cameras, each point's block damped by `damping` (the points take one step: far points, depth
    information ~1e-6 at a few hundred metres, would otherwise jump by their depth for a millimetre of
    camera motion)."""
    lin = linearize_static(T_c_w, X_w, obs_kf, obs_pt, meas, inv_sigma2, camera, min_depth, delta2)
    return reduce_static(lin, free, damping)
