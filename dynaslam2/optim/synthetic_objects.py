"""Synthetic windows with moving objects and known ground truth, for the object BA tests and benchmark.

A stereo car drives forward along +z; static points around; each object is a box-shaped point cloud
(points on its faces, in its object frame at the centroid, identity rotation at the first keyframe as
paper III-B) moving with a constant velocity (v_o, w_o) in its object frame, chained with eq. (5)
between consecutive keyframe times, so the ground truth follows the model exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynaslam2.config import ObjectOptimConfig
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse, make_pose, se3_exp
from dynaslam2.optim.object_ba import ObjectBAProblem
from dynaslam2.optim.object_pose import predict_object_pose
from dynaslam2.optim.synthetic import observe, perturb_poses, points_first_seen


@dataclass
class ObjectWindow:
    """Ground truth and the perturbed problem built from it."""

    T_c_w_true: np.ndarray  # (K, 4, 4)
    X_w_true: np.ndarray
    T_w_o_true: np.ndarray  # (F, 4, 4)
    velocity_true: np.ndarray  # (F, 6) (v_o, w_o)
    X_o_true: np.ndarray
    problem: ObjectBAProblem
    static_outlier: np.ndarray  # (M,) bool
    object_outlier: np.ndarray  # (M2,) bool


def box_points(rng: np.random.Generator, n: int, dims: tuple[float, float, float]) -> np.ndarray:
    """(n, 3) points on the faces of a box of `dims` (x, y, z) centred at 0, centroid moved to 0."""
    X = rng.uniform(-0.5, 0.5, (n, 3)) * dims
    face = rng.integers(0, 3, n)
    X[np.arange(n), face] = rng.choice([-0.5, 0.5], n) * np.asarray(dims)[face]
    return X - X.mean(0)


def make_object_window(
    rng: np.random.Generator,
    camera: StereoCamera,
    n_keyframes: int = 10,
    n_fixed: int = 2,
    duration: float = 2.0,
    speed: float = 8.0,
    n_static: int = 1500,
    static_track: int = 5,
    n_objects: int = 2,
    n_object_points: int = 80,
    outlier_fraction: float = 0.0,
    noise_scale: float = 1.0,
    static_depth: tuple[float, float] = (4.0, 45.0),
    object_depth: tuple[float, float] = (8.0, 25.0),
    camera_sigma: tuple[float, float] = (0.05, 0.005),
    object_sigma: tuple[float, float] = (0.1, 0.02),
    velocity_sigma: tuple[float, float] = (0.5, 0.05),
    point_sigma: float = 0.05,
    object_disparity_weight: float | None = ObjectOptimConfig().disparity_weight or None,
) -> ObjectWindow:
    """Keyframes at jittered times over `duration`, the first `n_fixed` fixed (and exact); objects in
    front of the first camera at `object_depth`, each seen at every keyframe where it is in view. Initial values:
    perturbed cameras and object poses at the free keyframes, velocities and points. The static observations'
    noise is isotropic (the static BA's model), the object observations' that of eq. (2)'s default
    disparity model (`synthetic.observe`'s `disparity_weight`)."""
    times = np.linspace(0.0, duration, n_keyframes) + np.concatenate([[0.0], rng.uniform(-0.3, 0.3, n_keyframes - 1)]) \
        * duration / n_keyframes
    twist = np.zeros((n_keyframes, 6))
    twist[:, 2] = speed * times
    twist[:, 4] = 0.03 * np.sin(times)
    T_c_w = inverse(se3_exp(twist))
    # static points: seen by up to `static_track` consecutive keyframes
    first, X_w = points_first_seen(rng, camera, T_c_w, n_static, static_depth)
    obs_pt = np.repeat(np.arange(n_static), static_track)
    obs_kf = np.repeat(first, static_track) + np.tile(np.arange(static_track), n_static)
    keep = obs_kf < n_keyframes
    obs_pt, obs_kf = obs_pt[keep], obs_kf[keep]
    X_c = np.einsum("mij,mj->mi", T_c_w[obs_kf, :3, :3], X_w[obs_pt]) + T_c_w[obs_kf, :3, 3]
    vis = X_c[:, 2] > 0.5
    vis[vis] = camera.in_image(camera.project(X_c[vis]))
    obs_pt, obs_kf, X_c = obs_pt[vis], obs_kf[vis], X_c[vis]
    static_obs = observe(rng, camera, X_c, X_c[:, 2] < 40 * camera.baseline, outlier_fraction, noise_scale=noise_scale)

    # objects: constant (v_o, w_o) in the object frame (camera axes at creation: x right, y down, z forward)
    T_w_o_traj, vel, X_o, pt_obj = [], [], [], []
    for k in range(n_objects):
        start = inverse(T_c_w[0]) @ make_pose(np.eye(3), np.array([rng.uniform(-6, 6), rng.uniform(0.5, 1.5),
                                                                   rng.uniform(*object_depth)]))
        v = np.array([rng.uniform(-1, 1), 0.0, speed + rng.uniform(-3, 3)])
        w = np.array([0.0, rng.uniform(-0.15, 0.15), 0.0])  # yaw about the (down) y axis
        traj = [start]
        for dt in np.diff(times):
            traj.append(predict_object_pose(traj[-1], v, w, dt))
        T_w_o_traj.append(np.array(traj))
        vel.append(np.concatenate([v, w]))
        X_o.append(box_points(rng, n_object_points, (1.8, 1.5, 4.5)))
        pt_obj.append(np.full(n_object_points, k))
    X_o, pt_obj = np.concatenate(X_o), np.concatenate(pt_obj)
    obj_id = np.repeat(np.arange(n_objects), n_keyframes)
    obj_frames = np.tile(np.arange(n_keyframes), n_objects)
    T_w_o = np.concatenate(T_w_o_traj)
    velocity = np.repeat(np.array(vel), n_keyframes, axis=0)
    # every point of the object in every observation, kept where in front and in the image
    oobs_f = np.repeat(np.arange(len(obj_id)), n_object_points)
    oobs_pt = (obj_id[:, None] * n_object_points + np.arange(n_object_points)).ravel()
    T_c_o = T_c_w[obj_frames] @ T_w_o
    X_c = np.einsum("mij,mj->mi", T_c_o[oobs_f, :3, :3], X_o[oobs_pt]) + T_c_o[oobs_f, :3, 3]
    vis = X_c[:, 2] > 0.5
    vis[vis] = camera.in_image(camera.project(X_c[vis]))
    oobs_f, oobs_pt, X_c = oobs_f[vis], oobs_pt[vis], X_c[vis]
    object_obs = observe(rng, camera, X_c, X_c[:, 2] < 40 * camera.baseline, outlier_fraction,
                         noise_scale=noise_scale, disparity_weight=object_disparity_weight)
    seen = np.bincount(oobs_f, minlength=len(obj_id)) > 0
    if not seen.all():  # drop object observations with no visible point (and renumber)
        new_index = np.cumsum(seen) - 1
        oobs_f = new_index[oobs_f]
        obj_id, obj_frames, T_w_o, velocity = obj_id[seen], obj_frames[seen], T_w_o[seen], velocity[seen]

    fixed = np.arange(n_keyframes) < n_fixed
    T_c_w_init = T_c_w.copy()
    T_c_w_init[~fixed] = perturb_poses(rng, T_c_w[~fixed], *camera_sigma)
    T_w_o_init = T_w_o.copy()  # observations at fixed keyframes are held (they define the object frames)
    free_obs = ~fixed[obj_frames]
    T_w_o_init[free_obs] = perturb_poses(rng, T_w_o[free_obs], *object_sigma)
    vel_init = velocity + np.concatenate([rng.normal(0, velocity_sigma[0], (len(velocity), 3)),
                                          rng.normal(0, velocity_sigma[1], (len(velocity), 3))], 1)
    problem = ObjectBAProblem(
        T_c_w=T_c_w_init, fixed=fixed, X_w=X_w + rng.normal(0, point_sigma, X_w.shape), obs_kf=obs_kf, obs_pt=obs_pt,
        meas=static_obs.meas, inv_sigma2=static_obs.inv_sigma2, obj_frames=obj_frames, obj_id=obj_id,
        T_w_o=T_w_o_init, v_o=vel_init[:, :3], w_o=vel_init[:, 3:], timestamps=times,
        X_o=X_o + rng.normal(0, point_sigma, X_o.shape), pt_obj=pt_obj, oobs_f=oobs_f, oobs_pt=oobs_pt,
        oobs_meas=object_obs.meas, oobs_inv_sigma2=object_obs.inv_sigma2)
    return ObjectWindow(T_c_w, X_w, T_w_o, velocity, X_o, problem, static_obs.outlier, object_obs.outlier)
