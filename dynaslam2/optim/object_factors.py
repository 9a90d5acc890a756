"""Python factors of the bundle adjustment with objects: eq. (4)-(5) and the direct form of eq. (2).

Eq. (4): one `gtsam.CustomFactor` per object over all its frame pairs, 12 rows per pair from the
moments of its (constant) points (`motion_factor_object`), or the reference per frame pair with 3 rows
per point (`motion_factor`, also with the points as variables); eq. (2) direct form: one per object
observation (`direct_projection_factor`). Closed-form numpy Jacobians. Eq. (3) is gtsam's built-in
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
from dynaslam2.geometry.se3 import hat, so3_exp, so3_right_jacobian
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


def motion_affine(R_a: np.ndarray, t_a: np.ndarray, R_b: np.ndarray, t_b: np.ndarray, velocity_a: np.ndarray,
                  dt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. (4) of R frame pairs as affine maps of the point: e_j = A x_j + c, returned as M = [A c] (R, 3, 4),
    with R_a dR(w_a dt) (R, 3, 3) and R_a v_a dt (R, 3) (eq. 5), for poses (R_a, t_a), (R_b, t_b), velocities
    (R, 6) and dt (R,)."""
    R_ad = R_a @ so3_exp(velocity_a[:, 3:] * dt[:, None])
    a_v = np.einsum("rij,rj->ri", R_a, velocity_a[:, :3] * dt[:, None])
    return np.concatenate([R_b - R_ad, (t_b - t_a - a_v)[:, :, None]], axis=2), R_ad, a_v


def motion_cost(M: np.ndarray, sigma: np.ndarray, X_o: np.ndarray, huber_delta2: float | None) -> float:
    """Summed Huber cost of eq. (4) over R pairs (`motion_affine`'s M, sigma (R,)) and the points X_o (n, 3)."""
    e = np.einsum("nl,ril->rni", np.hstack([X_o, np.ones((len(X_o), 1))]), M / sigma[:, None, None])
    c2 = np.einsum("rni,rni->rn", e, e)
    return float(0.5 * c2.sum() if huber_delta2 is None else huber_cost(c2, huber_delta2).sum())


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


def _adjoints(T: np.ndarray) -> np.ndarray:
    """(R, 6, 6) adjoints of (R, 4, 4) poses in gtsam's tangent order (omega, nu), as `adjoint`."""
    Ad = np.zeros((len(T), 6, 6))
    Ad[:, :3, :3] = Ad[:, 3:, 3:] = T[:, :3, :3]
    Ad[:, 3:, :3] = hat(T[:, :3, 3]) @ T[:, :3, :3]
    return Ad


def motion_factor_object(
    pair_keys: np.ndarray,
    parametrization: str,
    dt: np.ndarray,
    sigma: np.ndarray,
    huber_delta2: float | None,
    X_o: np.ndarray,
) -> gtsam.CustomFactor:
    """Eq. (4) of one object over all its frame pairs for its constant points `X_o`: one factor, 12 rows
    per pair instead of 3 per point, with exactly the normal equations and the Huber cost of the
    stacked `motion_factor`s of the pairs. `pair_keys`: (R, 5) or (R, 3) keys of each pair as
    `motion_factor`; `dt`, `sigma`: (R,).

    Each point's residual is affine in the point, e_j = A x_j + c = M (x_j; 1) with M = [A c] (3x4),
    so with the per-point Huber weights w_j (1 without kernel) and S = sum_j w_j (x_j; 1)(x_j; 1)^T =
    L L^T (4x4), the 12-vector vec(M L) / sigma and its Jacobian give sum_j w_j J_j^T J_j,
    sum_j w_j J_j^T e_j and sum_j w_j |e_j|^2 exactly (the Gauss-Newton system of the stacked form).
    The error evaluation (no Jacobians: LM's trial steps) returns a vector whose half squared norm is
    the summed Huber cost of the points. Vectorized over the pairs: one Python call per object.
    """
    via_camera = parametrization == "camera_in_object"
    n_pose = 4 if via_camera else 2
    pair_keys = np.asarray(pair_keys, dtype=np.int64).reshape(-1, n_pose + 1)
    dt, sigma = np.asarray(dt, dtype=float), np.asarray(sigma, dtype=float)
    R = len(pair_keys)
    keys, role = np.unique(pair_keys, return_inverse=True)
    role = role.reshape(R, n_pose + 1)
    is_pose = np.zeros(len(keys), dtype=bool)
    is_pose[role[:, :n_pose]] = True
    pose_keys, vel_keys = keys[is_pose].tolist(), keys[~is_pose].tolist()
    slot = np.cumsum(is_pose) - 1  # index of a pose key among the poses
    vslot = np.cumsum(~is_pose) - 1  # index of a velocity key among the velocities
    pose_role, vel_role = slot[role[:, :n_pose]], vslot[role[:, n_pose]]
    X_h = np.hstack([X_o, np.ones((len(X_o), 1))])
    pairs = np.arange(R)

    def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        T = np.array([values.atPose3(k).matrix() for k in pose_keys])[pose_role]  # (R, n_pose, 4, 4)
        velocity = np.array([values.atVector(k) for k in vel_keys])[vel_role]
        if via_camera:  # T_w_o = T_w_c Q^-1
            Q = T[:, 2:]
            R_wo = T[:, :2, :3, :3] @ np.swapaxes(Q[..., :3, :3], -1, -2)
            t_wo = T[:, :2, :3, 3] - np.einsum("rpij,rpj->rpi", R_wo, Q[..., :3, 3])
        else:
            R_wo, t_wo = T[..., :3, :3], T[..., :3, 3]
        R_a, R_b, t_a, t_b = R_wo[:, 0], R_wo[:, 1], t_wo[:, 0], t_wo[:, 1]
        M, R_ad, a_v = motion_affine(R_a, t_a, R_b, t_b, velocity, dt)
        if H is None:
            r = np.zeros(12 * R)
            r[0] = np.sqrt(2.0 * motion_cost(M, sigma, X_o, huber_delta2))
            return r
        M = M / sigma[:, None, None]  # [A c], whitened
        e = np.einsum("nl,ril->rni", X_h, M)
        c2 = np.einsum("rni,rni->rn", e, e)
        w = huber_scale(c2, huber_delta2, True) ** 2
        lam, U = np.linalg.eigh(np.einsum("nl,rn,nm->rlm", X_h, w, X_h))
        L = U * np.sqrt(np.maximum(lam, 0.0))[:, None, :]
        # d column l of [A c] (l < 3: A's columns, 3: c) on each key's right perturbation (omega, nu)
        G = np.zeros((3, R, 4, 3, 6))  # pose a, pose b, velocity
        G[0, :, :3, :, :3] = hat(np.swapaxes(R_ad, 1, 2)) @ R_a[:, None]
        G[0, :, 3, :, :3] = hat(a_v) @ R_a
        G[0, :, 3, :, 3:] = -R_a
        G[1, :, :3, :, :3] = -hat(np.swapaxes(R_b, 1, 2)) @ R_b[:, None]
        G[1, :, 3, :, 3:] = R_b
        G[2, :, :3, :, 3:] = (hat(np.swapaxes(R_ad, 1, 2))
                              @ (R_ad @ so3_right_jacobian(velocity[:, 3:] * dt[:, None]) * dt[:, None, None])[:, None])
        G[2, :, 3, :, :3] = -R_a * dt[:, None, None]
        B = np.einsum("rlk,grlij->grkij", L, G).reshape(3, R, 12, 6) / sigma[None, :, None, None]
        blocks = np.zeros((len(keys), R, 12, 6))
        if via_camera:
            B_a, B_b = B[0] @ _adjoints(Q[:, 0]), B[1] @ _adjoints(Q[:, 1])
            for j, block in enumerate((B_a, B_b, -B_a, -B_b, B[2])):
                blocks[role[:, j], pairs] += block
        else:
            for j in range(3):
                blocks[role[:, j], pairs] += B[j]
        H[:] = gtsam.JacobianVector(list(blocks.reshape(len(keys), 12 * R, 6)))
        return np.swapaxes(M @ L, 1, 2).ravel()

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(12 * R), keys.tolist(), error)


def direct_projection_factor(
    camera_key: int,
    object_key: int,
    point_keys: np.ndarray,
    meas: np.ndarray,
    inv_sigma2: np.ndarray,
    camera: StereoCamera,
    huber_delta_mono: float | None,
    huber_delta_stereo: float | None,
    disparity_weight: float | None = None,
) -> gtsam.CustomFactor:
    """Eq. (2) on (T_w_c, T_w_o, x_o) for the points of one object seen by one camera: u - pi(T_c_w T_w_o x_o).

    The reference formulation that the Q = T_o_c parametrization replaces, with the same objective as
    `add_stereo_factors` (GenericStereoFactor3D / pinhole projection factors): residual (u, v, u_R)
    of a stereo observation, or (u, v, k disparity) with `disparity_weight` k, (u, v) of a monocular
    one, sigma s, Huber on each observation's residual (delta of its dof). A point behind the camera
    gives gtsam's constant error 2 fx, zero Jacobian.
    """
    n = len(point_keys)
    stereo = meas[:, 2] >= 0
    sqrt_info = np.sqrt(inv_sigma2)
    delta2 = None
    if huber_delta_stereo is not None and huber_delta_mono is not None:
        delta2 = np.where(stereo, huber_delta_stereo**2, huber_delta_mono**2)
    rows = np.flatnonzero(np.column_stack([np.ones((n, 2), bool), stereo]).ravel())
    keys = [camera_key, object_key] + [int(k) for k in point_keys]

    def error(_: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        T_w_c = values.atPose3(camera_key).matrix()
        T_w_o = values.atPose3(object_key).matrix()
        X = np.array([values.atPoint3(int(k)) for k in point_keys])
        R_c_o = T_w_c[:3, :3].T @ T_w_o[:3, :3]
        X_c = X @ R_c_o.T + T_w_c[:3, :3].T @ (T_w_o[:3, 3] - T_w_c[:3, 3])
        front = X_c[:, 2] > 0
        X_front = np.where(front[:, None], X_c, [0.0, 0.0, 1.0])  # behind the camera: a constant error
        r = np.where(front[:, None], camera.project_stereo(X_front) - meas, 2.0 * camera.fx) * sqrt_info[:, None]
        r[~stereo, 2] = 0.0
        if disparity_weight is not None:
            r[:, 2] = np.where(stereo, disparity_weight * (r[:, 0] - r[:, 2]), 0.0)
        scale = huber_scale(np.einsum("ij,ij->i", r, r), delta2, H is not None)
        if H is not None:
            # d(u, v, u_R) / d X_c, whitened and weighted, zero behind the camera
            D = camera.project_stereo_jacobian(X_front)
            if disparity_weight is not None:
                D[:, 2] = disparity_weight * (D[:, 0] - D[:, 2])  # (mono rows: not in `rows`)
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
