"""Python factors of the bundle adjustment with objects: eq. (4)-(5) and the direct form of eq. (2).

One `gtsam.CustomFactor` per object per frame pair (eq. 4) or per object observation (eq. 2, direct
form), stacking all the object's points with closed-form numpy Jacobians. Eq. (3) is gtsam's built-in
`BetweenFactorVector` and the Q-parametrized eq. (2) the built-in stereo factors (object_ba.py).

Conventions: `T_w_o` maps object points into the world (paper T_WO); the velocity variable of an
object observation is the 6-vector (v_o, w_o) in the object frame at that time (object_pose.py,
eq. 5); gtsam perturbs a Pose3 on the right, `T Exp(xi)` with xi = (omega, nu), and a vector
additively. Huber kernels are applied inside the factors (noise model Unit) exactly as gtsam's Robust
noise model does: per-block weights sqrt(w) on the linearization, and an error whose half squared
norm is the Huber cost.
"""

from __future__ import annotations

import gtsam
import numpy as np

from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import hat
from dynaslam2.optim.reprojection import huber_cost


def adjoint(T: np.ndarray) -> np.ndarray:
    """6x6 adjoint of a (4, 4) pose in gtsam's tangent order (omega, nu): T Exp(xi) T^-1 = Exp(Ad xi)."""
    R, t = T[:3, :3], T[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = hat(t) @ R
    return Ad


def huber_scale(c2: np.ndarray, delta2: float | np.ndarray | None, linearize: bool) -> np.ndarray:
    """Per-block factor on whitened residuals (and Jacobians) reproducing gtsam's Huber Robust model:
    sqrt(min(1, delta/|r|)) when linearizing, sqrt(2 huber(|r|^2) / |r|^2) when evaluating the error."""
    if delta2 is None:
        return np.ones_like(c2)
    c2 = np.maximum(c2, 1e-300)
    if linearize:
        return np.sqrt(np.minimum(1.0, np.sqrt(delta2 / c2)))
    return np.sqrt(2.0 * huber_cost(c2, delta2) / c2)


_HAT_COLUMNS = np.array([1, 2, 3, 5, 6, 7])
_HAT_SOURCE = np.array([2, 1, 2, 0, 1, 0])
_HAT_SIGN = np.array([-1.0, 1.0, 1.0, -1.0, -1.0, 1.0])


def _hat_rows(X: np.ndarray) -> np.ndarray:
    """(3n, 3): the skew matrices [x_j]x of (n, 3) vectors stacked by rows (one indexed assignment)."""
    K = np.zeros((len(X), 9))
    K[:, _HAT_COLUMNS] = X[:, _HAT_SOURCE] * _HAT_SIGN
    return K.reshape(-1, 3)


def motion_residuals(
    T_w_o_a: np.ndarray, T_w_o_b: np.ndarray, velocity_a: np.ndarray, dt: float, X_o: np.ndarray,
    jacobians: bool = True,
) -> tuple[np.ndarray, ...]:
    """Eq. (4) for every point: e_j = (T_w_o^b - T_w_o^a dT(v_a, w_a, dt)) x_j, with dT of eq. (5).

    Returns e (n, 3) and, with `jacobians`, its Jacobians stacked over the points, rows 3j..3j+2 for
    point j: (3n, 6) on the right perturbations of T_w_o^a and of T_w_o^b (gtsam order (omega, nu)),
    (3n, 6) on velocity_a = (v, w), and the (3, 3) Jacobian on each x_j (the same for every point).
    Uses R [x]x = [R x]x R so that every block is one (3n, 3) @ (3, 3) product.
    """
    v, w = velocity_a[:3], velocity_a[3:]
    R_a, t_a, R_b, t_b = T_w_o_a[:3, :3], T_w_o_a[:3, 3], T_w_o_b[:3, :3], T_w_o_b[:3, 3]
    R_d = gtsam.Rot3.Expmap(w * dt).matrix()
    R_ad = R_a @ R_d
    J_x = R_b - R_ad
    e = X_o @ J_x.T + (t_b - t_a - R_a @ (v * dt))
    if not jacobians:
        return (e,)
    n = len(X_o)
    X_ad = X_o @ R_ad.T
    J = np.empty((3, n, 3, 6))  # J_a, J_b, J_vel
    J[0, :, :, :3] = (_hat_rows(X_ad + R_a @ (v * dt)) @ R_a).reshape(n, 3, 3)  # -R_a [-[y]x, I], y = dT x
    J[0, :, :, 3:] = -R_a
    J[1, :, :, :3] = (_hat_rows(X_o @ R_b.T) @ -R_b).reshape(n, 3, 3)  # R_b [-[x]x, I]
    J[1, :, :, 3:] = R_b
    J[2, :, :, :3] = -R_a * dt
    # d Exp(w dt) x / dw = -R_d [x]x J_r(w dt) dt (gtsam's ExpmapDerivative is the right Jacobian)
    J_r = np.asarray(gtsam.Rot3.ExpmapDerivative(w * dt)) * dt
    J[2, :, :, 3:] = (_hat_rows(X_ad) @ (R_ad @ J_r)).reshape(n, 3, 3)
    J = J.reshape(3, 3 * n, 6)
    return e, J[0], J[1], J[2], J_x


def _compose_inverse(T_w_c: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """T_w_c Q^-1 for (4, 4) rigid transforms."""
    T = np.eye(4)
    T[:3, :3] = T_w_c[:3, :3] @ Q[:3, :3].T
    T[:3, 3] = T_w_c[:3, 3] - T[:3, :3] @ Q[:3, 3]
    return T


def motion_factor(
    keys: list[int],
    parametrization: str,
    dt: float,
    sigma: float,
    huber_delta2: float | None,
    X_o: np.ndarray | None = None,
    point_keys: np.ndarray | None = None,
) -> gtsam.CustomFactor:
    """Eq. (4) of one object between its observations a and b (dt apart), all its points stacked.

    `parametrization == "camera_in_object"`: keys = [T_w_c^a, T_w_c^b, Q^a, Q^b, velocity_a] with
    Q = T_o_c (Pose3) and T_w_o = T_w_c Q^-1; `"direct"`: keys = [T_w_o^a, T_w_o^b, velocity_a].
    The points are the Point3 variables `point_keys` (exact joint term) or the constants `X_o`.
    Residuals are whitened by `sigma` (isotropic) and Huber-weighted per point (`huber_delta2`).
    """
    via_camera = parametrization == "camera_in_object"
    n_pose = 4 if via_camera else 2
    if point_keys is not None:
        all_keys = list(keys) + [int(k) for k in point_keys]
        n = len(point_keys)
    else:
        all_keys = list(keys)
        n = len(X_o)

    def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        poses = [values.atPose3(k).matrix() for k in keys[:n_pose]]
        if via_camera:
            T_w_c_a, T_w_c_b, Q_a, Q_b = poses
            T_w_o_a, T_w_o_b = _compose_inverse(T_w_c_a, Q_a), _compose_inverse(T_w_c_b, Q_b)
        else:
            T_w_o_a, T_w_o_b = poses
        X = X_o if point_keys is None else np.array([values.atPoint3(int(k)) for k in point_keys])
        out = motion_residuals(T_w_o_a, T_w_o_b, values.atVector(keys[n_pose]), dt, X, H is not None)
        e = out[0] / sigma
        s = huber_scale(np.einsum("ij,ij->i", e, e), huber_delta2, H is not None)[:, None]
        if H is not None:
            J_a, J_b, J_vel, J_x = out[1:]
            w = np.repeat(s[:, 0] / sigma, 3)[:, None]  # per row
            J_a, J_b = w * J_a, w * J_b
            if via_camera:
                # T_w_c Exp(xi) Q^-1 = T_w_o Exp(Ad_Q xi) and T_w_c (Q Exp(xi))^-1 = T_w_o Exp(-Ad_Q xi)
                J_a, J_b = J_a @ adjoint(Q_a), J_b @ adjoint(Q_b)
                H[0], H[1], H[2], H[3] = J_a, J_b, -J_a, -J_b
            else:
                H[0], H[1] = J_a, J_b
            H[n_pose] = w * J_vel
            if point_keys is not None:
                J_pts = np.zeros((n, 3, n, 3))
                J_pts[np.arange(n), :, np.arange(n), :] = w.reshape(n, 3, 1) * J_x
                H[n_pose + 1:] = gtsam.JacobianVector(list(J_pts.reshape(3 * n, n, 3).transpose(1, 0, 2)))
        return (e * s).ravel()

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3 * n), all_keys, error)


_MOMENT_BASIS = np.vstack([np.zeros(3), np.eye(3)])  # x = 0, e_1, e_2, e_3: the columns of [A c] (motion_factor_moments)


def motion_factor_moments(
    keys: list[int],
    parametrization: str,
    dt: float,
    sigma: float,
    huber_delta2: float | None,
    X_o: np.ndarray,
) -> gtsam.CustomFactor:
    """Eq. (4) of one object between its observations a and b for constant points `X_o`, in 12 rows
    instead of 3 per point, with exactly the normal equations and the Huber cost of `motion_factor`.

    Each point's residual is affine in the point, e_j = A x_j + c = M (x_j; 1) with M = [A c] (3x4,
    from `motion_residuals` at x = 0, e_1, e_2, e_3), so with the per-point Huber weights w_j (1
    without kernel) and S = sum_j w_j (x_j; 1)(x_j; 1)^T = L L^T (4x4), the 12-vector vec(M L) / sigma
    and its Jacobian give sum_j w_j J_j^T J_j, sum_j w_j J_j^T e_j and sum_j w_j |e_j|^2 exactly
    (Gauss-Newton system of the stacked form, linearization at one point). The error evaluation (no
    Jacobians: LM's trial steps) returns a vector whose half squared norm is the summed Huber cost of
    the points, as the stacked factor's. Keys as `motion_factor`.
    """
    via_camera = parametrization == "camera_in_object"
    n_pose = 4 if via_camera else 2
    X_h = np.hstack([X_o, np.ones((len(X_o), 1))])

    def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        poses = [values.atPose3(k).matrix() for k in keys[:n_pose]]
        if via_camera:
            T_w_c_a, T_w_c_b, Q_a, Q_b = poses
            T_w_o_a, T_w_o_b = _compose_inverse(T_w_c_a, Q_a), _compose_inverse(T_w_c_b, Q_b)
        else:
            T_w_o_a, T_w_o_b = poses
        out = motion_residuals(T_w_o_a, T_w_o_b, values.atVector(keys[n_pose]), dt, _MOMENT_BASIS, H is not None)
        M = np.column_stack([(out[0][1:] - out[0][0]).T, out[0][0]]) / sigma  # whitened [A c]
        e = X_h @ M.T
        c2 = np.einsum("ij,ij->i", e, e)
        if H is None:
            cost2 = c2.sum() if huber_delta2 is None else 2.0 * huber_cost(c2, huber_delta2).sum()
            r = np.zeros(12)
            r[0] = np.sqrt(cost2)
            return r
        w = huber_scale(c2, huber_delta2, True) ** 2
        lam, U = np.linalg.eigh((X_h * w[:, None]).T @ X_h)
        L = U * np.sqrt(np.maximum(lam, 0.0))
        blocks = []
        for J in out[1:4]:  # J_a, J_b, J_vel: (4 basis points x 3, 6)
            G = J.reshape(4, 3, 6) / sigma
            G = np.concatenate([G[1:] - G[0], G[:1]])  # d column l of M
            blocks.append(np.einsum("lk,lij->kij", L, G).reshape(12, 6))
        J_a, J_b, J_vel = blocks
        if via_camera:
            J_a, J_b = J_a @ adjoint(Q_a), J_b @ adjoint(Q_b)
            H[0], H[1], H[2], H[3] = J_a, J_b, -J_a, -J_b
        else:
            H[0], H[1] = J_a, J_b
        H[n_pose] = J_vel
        return (M @ L).T.ravel()

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(12), list(keys), error)


def direct_projection_factor(
    camera_key: int,
    object_key: int,
    point_keys: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    camera: StereoCamera,
    huber_delta_mono: float | None,
    huber_delta_stereo: float | None,
) -> gtsam.CustomFactor:
    """Eq. (2) on (T_w_c, T_w_o, x_o) for the points of one object seen by one camera: u - pi(T_c_w T_w_o x_o).

    The reference formulation that the Q = T_o_c parametrization replaces, with the same objective as
    `add_stereo_factors` (GenericStereoFactor3D / pinhole projection factors): residual (u, v, u_R)
    of a stereo observation, (u, v) of a monocular one, sigma s, Huber on each observation's residual
    (delta of its dof). A point behind the camera gives gtsam's constant error 2 fx, zero Jacobian.
    """
    n = len(point_keys)
    stereo = meas[:, 2] >= 0
    sqrt_info = np.sqrt(inv_sigma2)
    delta2 = None
    if huber_delta_stereo is not None and huber_delta_mono is not None:
        delta2 = np.where(stereo, huber_delta_stereo**2, huber_delta_mono**2)
    rows = np.flatnonzero(np.column_stack([np.ones((n, 2), bool), stereo]).ravel())
    fx, fy, cx, cy, bf = camera.fx, camera.fy, camera.cx, camera.cy, camera.bf
    keys = [camera_key, object_key] + [int(k) for k in point_keys]

    def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        T_w_c = values.atPose3(camera_key).matrix()
        T_w_o = values.atPose3(object_key).matrix()
        X = np.array([values.atPoint3(int(k)) for k in point_keys])
        R_c_o = T_w_c[:3, :3].T @ T_w_o[:3, :3]
        X_c = X @ R_c_o.T + T_w_c[:3, :3].T @ (T_w_o[:3, 3] - T_w_c[:3, 3])
        x, y, z = X_c.T
        front = z > 0
        inv_z = 1.0 / np.where(front, z, 1.0)
        u = fx * x * inv_z + cx
        pred = np.stack([u, fy * y * inv_z + cy, u - bf * inv_z], -1)
        r = np.where(front[:, None], pred - meas, 2.0 * fx) * sqrt_info[:, None]
        r[~stereo, 2] = 0.0
        scale = huber_scale(np.einsum("ij,ij->i", r, r), delta2, H is not None)
        if H is not None:
            # d(u, v, u_R) / d X_c, whitened and weighted, zero behind the camera
            D = np.zeros((n, 3, 3))
            D[:, 0, 0] = D[:, 2, 0] = fx * inv_z
            D[:, 0, 2] = -fx * x * inv_z**2
            D[:, 2, 2] = -(fx * x - bf) * inv_z**2
            D[:, 1, 1] = fy * inv_z
            D[:, 1, 2] = -fy * y * inv_z**2
            D *= (scale * sqrt_info * front)[:, None, None]
            J_cam = np.concatenate([D @ hat(X_c), -D], -1)  # X_c' = X_c + [X_c]x omega - nu
            D_o = D @ R_c_o
            J_obj = np.concatenate([-D_o @ hat(X), D_o], -1)  # X_c' = X_c + R_c_o (omega x x + nu)
            H[0] = J_cam.reshape(-1, 6)[rows]
            H[1] = J_obj.reshape(-1, 6)[rows]
            J_pts = np.zeros((n, 3, n, 3))
            J_pts[np.arange(n), :, np.arange(n), :] = D_o
            H[2:] = gtsam.JacobianVector(list(J_pts.reshape(3 * n, n, 3)[rows].transpose(1, 0, 2)))
        return (r * scale[:, None]).ravel()[rows]

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(rows)), keys, error)
