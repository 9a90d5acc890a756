"""The static reprojection terms (paper eq. 1) of a BA window reduced to its free cameras (Schur complement).

Linearized at the current estimate (Huber weights of that estimate, as gtsam's Robust model), the static
terms are the quadratic cost + g^T d + 1/2 d^T H d in the camera and point increments; eliminating the
points gives the reduced camera system S = H_cc - H_cp H_pp^-1 H_pc, s = g_c - H_cp H_pp^-1 g_p (points
first, as the SCHUR elimination order), and once the cameras are solved each point moves by
-H_pp^-1 (g_p + H_pc d_c) (back-substitution): without damping, exactly
gtsam's linearization and partial elimination of the same GenericStereoFactor3D / projection factors
(tests/test_static_schur.py), computed in vectorized numpy (closed-form stereo Jacobians and 3x3 point
blocks, one block-sparse product for the reduction) instead of building, linearizing and eliminating ~20k
factors.

`StaticSchur.factor` puts the reduced system into a gtsam graph as one factor on the free camera
poses (T_w_c, right perturbations), whose error is the quadratic model of the static cost: the BA
with objects (object_ba.py, `optim.objects.static_reduced`) then optimizes cameras and objects with
the static terms linearized once, the points following by back-substitution. The object reprojection terms
(eq. 2) reduce the same way to the object observations' poses Q = T_o_c (`optim.objects.object_points_reduced`:
the observations as the "cameras", the disparity rows of eq. 2's noise model), one factor per object
(`StaticSchur.factors`).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.sparse as sp
from scipy.linalg import solve_triangular

from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.optim.gtsam_utils import pose3_from_matrix
from dynaslam2.optim.reprojection import disparity_residuals, is_stereo, residuals


@dataclass
class StaticSchur:
    """Reduced camera system of the static terms and what the back-substitution needs."""

    cams: np.ndarray  # (C,) indices of the free cameras, the order of S's 6-blocks
    S: np.ndarray  # (6C, 6C)
    s: np.ndarray  # (6C,)
    points: np.ndarray  # (P',) indices of the points eliminated
    L_pp: np.ndarray  # (6, P') Cholesky factors of the damped point blocks (`_cholesky3`)
    g_p: np.ndarray  # (3, P')
    obs_cam: np.ndarray  # (M',) row in `cams` of each used observation with a free camera
    obs_point: np.ndarray  # (M',) row in `points`
    W: np.ndarray  # (6, 3, M') H_cp block of each such observation
    cost: float  # 1/2 sum of the whitened, Huber-weighted squared residuals at the linearization point

    def factor(self, keys: np.ndarray, T_w_c: np.ndarray) -> gtsam.CustomFactor:
        """One factor on the free cameras' Pose3 keys (`keys[i]` = camera `cams[i]` at `T_w_c[i]`, the
        linearization point): error (A d - b, floor) with A^T A = S, -A^T b = s (`square_root`) and d =
        Local(T_w_c, pose) per camera; half its squared norm is the quadratic model of the static cost."""
        return self.factors(keys, T_w_c, np.zeros(len(self.cams), dtype=np.int64))[0]

    def factors(self, keys: np.ndarray, T_w_c: np.ndarray, groups: np.ndarray) -> list[gtsam.CustomFactor]:
        """`factor` split into one factor per group of cameras (`groups`: (C,) label of each camera of `cams`),
        for groups that see no point in common (S is zero between them: the objects of eq. 2): the same
        quadratic model, and gtsam's elimination keeps the groups apart. The model's constant row rides on
        the first factor."""
        systems = []
        for g in np.unique(groups).tolist():
            sel = np.flatnonzero(groups == g)
            idx = (6 * sel[:, None] + np.arange(6)).ravel()
            systems.append((sel, *square_root(self.S[np.ix_(idx, idx)], self.s[idx])))
        # the model's minimum as a constant row: the factors' error is the whole quadratic model of the
        # cost, 1/2 sum |A d - b|^2 + cost - 1/2 sum |b|^2, so that LM's relative decrease is on the full cost
        floor = np.sqrt(2.0 * max(self.cost - 0.5 * sum(b @ b for _, _, b in systems), 0.0))
        return [_quadratic_factor(A, b, floor if i == 0 else None, keys[sel], T_w_c[sel])
                for i, (sel, A, b) in enumerate(systems)]

    def point_steps(self, d_cams: np.ndarray) -> np.ndarray:
        """(P', 3) point increments for (C, 6) camera increments: -H_pp^-1 (g_p + sum H_pc d_c)."""
        d = d_cams[self.obs_cam].T  # (6, M')
        Wd = [(self.W[:, j] * d).sum(axis=0) for j in range(3)]
        rhs = self.g_p + np.array([np.bincount(self.obs_point, Wd[j], len(self.points)) for j in range(3)])
        return -_cholesky3_solve(self.L_pp, rhs).T


def square_root(S: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) with A^T A = S, -A^T b = s: A = L^T for S = L L^T (S is positive definite when the fixed
    cameras hold the gauge); else from the eigen-decomposition of S, its null space dropped (eigh
    costs ~100x the Cholesky factorization with multithreaded OpenBLAS on a loaded machine)."""
    S = 0.5 * (S + S.T)
    try:
        L = np.linalg.cholesky(S)
        return L.T, -solve_triangular(L, s, lower=True)
    except np.linalg.LinAlgError:
        lam, V = np.linalg.eigh(S)
        keep = lam > max(lam[-1], 0.0) * 1e-12
        return np.sqrt(lam[keep])[:, None] * V[:, keep].T, -(V[:, keep].T @ s) / np.sqrt(lam[keep])


def _quadratic_factor(A: np.ndarray, b: np.ndarray, floor: float | None, keys: np.ndarray,
                      T_w_c: np.ndarray) -> gtsam.CustomFactor:
    """A factor on Pose3 `keys` linearized at `T_w_c`: error (A d - b[, floor]), d = Local(T_w_c, pose) per key."""
    blocks = [np.ascontiguousarray(A[:, 6 * i:6 * i + 6]) for i in range(len(keys))]
    lin = [pose3_from_matrix(T) for T in T_w_c]
    key_list = [int(k) for k in keys]
    tail = np.zeros((0 if floor is None else 1, 6))
    constant = np.array([] if floor is None else [floor])

    def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        d = np.empty(6 * len(key_list))
        for i, (key, T0) in enumerate(zip(key_list, lin)):
            if H is None:
                d[6 * i:6 * i + 6] = T0.localCoordinates(values.atPose3(key))
            else:
                J = np.zeros((6, 6), order="F")
                d[6 * i:6 * i + 6] = T0.localCoordinates(values.atPose3(key), None, J)
                H[i] = np.vstack([blocks[i] @ J, tail])
        return np.append(A @ d - b, constant)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(b) + len(constant)), key_list, error)


@dataclass
class StaticLinearization:
    """The static terms linearized at one estimate: whitened, Huber-weighted Jacobian rows and residuals
    of every observation (the camera columns (omega, nu) of T_w_c Exp(omega, nu), then the point's X_w)."""

    obs_kf: np.ndarray  # (M,) camera of each observation
    obs_pt: np.ndarray  # (M,) point of each observation
    J_t: np.ndarray  # (9, 3, M) Jacobian entries [column, row], each over the observations (contiguous)
    r: np.ndarray  # (M, 3) whitened, weighted residuals (rows of monocular observations: third 0)
    cost: float  # 1/2 sum |r|^2

    def model_cost(self, d_cams: np.ndarray, d_points: np.ndarray) -> float:
        """1/2 sum |J d + r|^2, the linear model's cost for (K, 6) camera and (P, 3) point increments."""
        d = np.concatenate([d_cams[self.obs_kf], d_points[self.obs_pt]], axis=1).T
        e = np.einsum("jim,jm->im", self.J_t, d, optimize=True) + self.r.T
        return 0.5 * float(np.einsum("ij,ij->", e, e))


def linearize_static(T_c_w: np.ndarray, X_w: np.ndarray, obs_kf: np.ndarray, obs_pt: np.ndarray,
                     meas: np.ndarray, inv_sigma2: np.ndarray, camera: StereoCamera, min_depth: float,
                     delta2: np.ndarray | None, disparity_weight: float | None = None) -> StaticLinearization:
    """Linearize the given observations at (T_c_w, X_w), with Huber weights as gtsam's Robust model
    (`delta2`: (M,) delta^2 per observation; None: no kernel). Observations closer than `min_depth`
    contribute nothing. `disparity_weight` k: stereo rows [u, v, k disparity] (`disparity_residuals`, the
    object terms of eq. 2) instead of [u, v, u_right]."""
    R, t = T_c_w[obs_kf, :3, :3], T_c_w[obs_kf, :3, 3]
    X_c = np.einsum("mij,mj->mi", R, X_w[obs_pt]) + t
    r = residuals(camera, X_c, meas)
    if disparity_weight is not None:
        r = disparity_residuals(r, meas, disparity_weight)
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
    J_t = np.zeros((9, 3, len(z)))  # [column, row]: each entry over the observations
    J_t[0, 0], J_t[1, 0], J_t[2, 0], J_t[3, 0], J_t[5, 0] = -c * y, c * x - a * z, a * y, -a, -c
    J_t[0, 1], J_t[1, 1], J_t[2, 1], J_t[4, 1], J_t[5, 1] = b * z - d * y, d * x, -b * x, -b, -d
    J_t[0, 2], J_t[1, 2], J_t[2, 2], J_t[3, 2], J_t[5, 2] = -e * y, e * x - a2 * z, a2 * y, -a2, -e
    R_t = R.transpose(1, 2, 0)  # (3, 3, M)
    J_t[6:, 0] = a * R_t[0] + c * R_t[2]
    J_t[6:, 1] = b * R_t[1] + d * R_t[2]
    J_t[6:, 2] = a2 * R_t[0] + e * R_t[2]
    if disparity_weight is not None:  # the third row: k (u - u_right), linear in the rows above
        J_t[:, 2] = np.where(stereo, disparity_weight * (J_t[:, 0] - J_t[:, 2]), 0.0)
    r = sw[:, None] * r
    return StaticLinearization(obs_kf, obs_pt, J_t, r, 0.5 * float(np.einsum("ij,ij->", r, r)))


def reduce_static(lin: StaticLinearization, free: np.ndarray, damping: float) -> StaticSchur:
    """Eliminate the points of a linearization, each point's block damped as Levenberg-Marquardt's
    H_pp + damping I (whitened units); damping 0 is the plain Schur complement (every point determined).
    `free`: (K,) bool, the cameras kept as variables (the others are constants). Raises
    np.linalg.LinAlgError when a damped point block is not positive definite."""
    J = lin.J_t
    r = lin.r.T
    points, obs_point = np.unique(lin.obs_pt, return_inverse=True)
    n_p = len(points)
    # normal-equation blocks [[H_cc, W], [W^T, H_pp]] and gradient (g_c, g_p), entry by entry over the
    # observations (each a sum over the 3 residual rows), the point ones summed per point (bincount)
    Jp = J[6:]
    H_pp = [np.bincount(obs_point, _rows_dot(Jp[i], Jp[j]), n_p) for i, j in _UPPER3]
    for i in (0, 3, 5):  # the diagonal of (0,0) (0,1) (0,2) (1,1) (1,2) (2,2)
        H_pp[i] = H_pp[i] + damping
    L_pp = _cholesky3(np.array(H_pp))
    g_p = np.array([np.bincount(obs_point, _rows_dot(Jp[i], r), n_p) for i in range(3)])

    K = len(free)
    cams = np.flatnonzero(free)
    C, n = len(cams), 6 * len(cams)
    cam_row = np.full(K, -1, dtype=np.int64)
    cam_row[cams] = np.arange(C)
    on_free = np.flatnonzero(cam_row[lin.obs_kf] >= 0)
    on_free = on_free[np.argsort(lin.obs_kf[on_free], kind="stable")]  # grouped by camera (contiguous columns)
    oc, op = cam_row[lin.obs_kf[on_free]], obs_point[on_free]
    indptr = np.concatenate([[0], np.cumsum(np.bincount(oc, minlength=C))])
    Jc, Jp, r = J[:6, :, on_free], Jp[:, :, on_free], r[:, on_free]
    W = np.einsum("ikm,jkm->ijm", Jc, Jp, optimize=True)  # (6, 3, M'): the H_cp block of each observation
    # each camera's H_cc and g_c - W H_pp^-1 g_p: one product over its stacked rows
    Wy = np.einsum("ijm,jm->im", W, _cholesky3_solve(L_pp, g_p)[:, op])
    S = np.zeros((C, 6, C, 6))
    s = np.zeros((C, 6))
    for c in range(C):
        rows = slice(indptr[c], indptr[c + 1])
        Jc_rows = Jc[:, :, rows].reshape(6, -1)
        S[c, :, c, :] = Jc_rows @ Jc_rows.T
        s[c] = Jc_rows @ r[:, rows].ravel() - Wy[:, rows].sum(axis=1)
    # reduction sum_p W_p H_pp^-1 W_p^T = U U^T with U = W L^-T (H_pp = L L^T): a block-sparse (6C, 3P) matrix
    # whose 6x3 blocks are the observations grouped by camera (scipy's BSR product: ~3x its CSR one)
    U = np.ascontiguousarray(_cholesky3_forward(L_pp[:, op], W).transpose(2, 0, 1))
    Us = sp.bsr_matrix((U, op, indptr), shape=(n, 3 * n_p))
    S = S.reshape(n, n) - (Us @ Us.T).toarray()
    return StaticSchur(cams, S, s.ravel(), points, L_pp, g_p, oc, op, W, lin.cost)


_UPPER3 = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the entries of a symmetric 3x3 block, in order


def _rows_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M,) sum over the 3 residual rows of a * b, for (3, M) entries `a`, `b`."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cholesky3(H: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors L (L L^T = H) of symmetric 3x3 blocks given by their `_UPPER3` entries (6, P),
    as (l00, l10, l20, l11, l21, l22) (6, P); np.linalg.LinAlgError when one is not positive definite."""
    h00, h01, h02, h11, h12, h22 = H
    with np.errstate(invalid="ignore", divide="ignore"):
        l00 = np.sqrt(h00)
        l10, l20 = h01 / l00, h02 / l00
        l11 = np.sqrt(h11 - l10 * l10)
        l21 = (h12 - l20 * l10) / l11
        l22 = np.sqrt(h22 - l20 * l20 - l21 * l21)
    L = np.array([l00, l10, l20, l11, l21, l22])
    if not np.all(L[[0, 3, 5]] > 0.0):  # also catches NaN
        raise np.linalg.LinAlgError("a point block is not positive definite")
    return L


def _cholesky3_forward(L: np.ndarray, v: np.ndarray) -> np.ndarray:
    """L^-1 v for (6, P) factors `L` (`_cholesky3`) and vectors v (..., 3, P)."""
    l00, l10, l20, l11, l21, l22 = L
    z0 = v[..., 0, :] / l00
    z1 = (v[..., 1, :] - l10 * z0) / l11
    z2 = (v[..., 2, :] - l20 * z0 - l21 * z1) / l22
    return np.stack([z0, z1, z2], axis=-2)


def _cholesky3_solve(L: np.ndarray, v: np.ndarray) -> np.ndarray:
    """H^-1 v (H = L L^T) for (6, P) factors `L` and (3, P) vectors `v`."""
    l00, l10, l20, l11, l21, l22 = L
    z0, z1, z2 = _cholesky3_forward(L, v)
    x2 = z2 / l22
    x1 = (z1 - l21 * x2) / l11
    x0 = (z0 - l10 * x1 - l20 * x2) / l00
    return np.array([x0, x1, x2])


def static_schur(T_c_w: np.ndarray, free: np.ndarray, X_w: np.ndarray, obs_kf: np.ndarray, obs_pt: np.ndarray,
                 meas: np.ndarray, inv_sigma2: np.ndarray, camera: StereoCamera, min_depth: float,
                 delta2: np.ndarray | None, damping: float, disparity_weight: float | None = None) -> StaticSchur:
    """`linearize_static` then `reduce_static`: the static terms at (T_c_w, X_w) reduced to the free
    cameras, each point's block damped by `damping` (the points take one step: far points, depth
    information ~1e-6 at a few hundred metres, would otherwise jump by their depth for a millimetre of
    camera motion)."""
    lin = linearize_static(T_c_w, X_w, obs_kf, obs_pt, meas, inv_sigma2, camera, min_depth, delta2,
                           disparity_weight)
    return reduce_static(lin, free, damping)
