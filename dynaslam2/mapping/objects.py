"""Local bundle adjustment with objects on a new keyframe (paper III-D): assembles the window from
the static map and the object map, runs `optim.object_ba.object_bundle_adjustment`, writes back (each object
frame kept where it was on its body: `keep_object_origins`).

Cases (the camera-weak-only case is the static local BA of `LocalMapper.local_ba`):
- object weak only: the weak objects' poses, velocities and points, and the keyframes that observe
  them within the last `optim.objects.tail_seconds` (free), the static points they see held constant;
- camera and object weak: the static local window (the new keyframe and its covisible keyframes,
  free; the keyframes outside it that see its points most, fixed), its points, and the weak objects'
  observations in those keyframes within the temporal tail, jointly.
In both, object observations older than the tail are left out (they keep their estimates).
"""

from __future__ import annotations

import numpy as np

from dynaslam2.config import SlamConfig
from dynaslam2.map.keyframe import KeyFrame
from dynaslam2.map.map import Map
from dynaslam2.map.objects import ObjectMap, ObjectObservation, ObjectTrack
from dynaslam2.optim.object_ba import ObjectBAProblem, object_bundle_adjustment
from dynaslam2.time_windows import within
from dynaslam2.tracking.camera import rigid


def _static_window(kf: KeyFrame, map_: Map, config: SlamConfig) -> tuple[list[int], list[int], np.ndarray]:
    """(free keyframe ids, fixed keyframe ids, point ids) of the static local window around `kf`."""
    cfg = config.mapping
    local = [kf.id] + map_.covisible(kf.id, cfg.ba_max_keyframes - 1)
    pts = map_.points_of_keyframes(local)
    obs_kf, _, _ = map_.observers(pts)
    ids_out, counts = np.unique(obs_kf[~np.isin(obs_kf, local)], return_counts=True)
    fixed = sorted(ids_out[np.lexsort((ids_out, -counts))[: cfg.ba_max_fixed_keyframes]].tolist())
    if min(map_.keyframes) in local:
        local.remove(min(map_.keyframes))
        fixed = sorted(fixed + [min(map_.keyframes)])
    return local, fixed, pts


def keep_object_origins(X_o_before: np.ndarray, X_o: np.ndarray, pt_obj: np.ndarray, T_w_o: np.ndarray,
                        v_o: np.ndarray, w_o: np.ndarray,
                        obj_id: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The BA's object points `X_o` (object `pt_obj`), poses `T_w_o` and linear velocities `v_o` (observations of
    object `obj_id`) re-expressed in object frames translated so that each object's points keep their mean
    position from before the BA (`X_o_before`): the same world points and motion, (X_o, T_w_o, v_o).

    The BA fixes each object frame's gauge by holding one pose, the tracker's, whose position is the
    tracking filter's and not the one its points were measured at: the BA then moves the object frame along
    the body (all its points shift together). Output trajectories must follow one body-fixed point, and the
    object's points outside the window keep their coordinates. A translation d of the frame (X' = X + d,
    T' = T [I, -d]) changes eq. (5)'s linear velocity to v - w x d (first order in dt), the angular one not."""
    X_o, T_w_o, v_o = X_o.copy(), T_w_o.copy(), v_o.copy()
    n = int(max(pt_obj.max(initial=-1), obj_id.max(initial=-1))) + 1
    counts = np.bincount(pt_obj, minlength=n)
    shift = np.column_stack([np.bincount(pt_obj, X_o_before[:, i] - X_o[:, i], minlength=n) for i in range(3)])
    shift = shift.astype(float) / np.maximum(counts, 1)[:, None]  # float when no object has a point in the window
    X_o += shift[pt_obj]
    d = shift[obj_id]
    T_w_o[:, :3, 3] -= np.einsum("fij,fj->fi", T_w_o[:, :3, :3], d)
    v_o -= np.cross(w_o, d)
    return X_o, T_w_o, v_o


def write_back(track: ObjectTrack, o: ObjectObservation, T_w_o: np.ndarray, v_o: np.ndarray,
               w_o: np.ndarray) -> None:
    """The BA's pose and velocities into observation `o` of `track`. The newest observation is the tracking
    filters' state: the position filter restarts from the BA's position and keeps its own velocity, while the
    observation takes the BA's, which the constant-velocity prediction extrapolates (giving the observation the
    filter's velocity instead measured no better: bench_dynamic's four seed groups, world 3, object ATE 0.239 /
    0.176 / 0.190 / 0.202 -> 0.230 / 0.180 / 0.193 / 0.210 m, two unoccluded id switches, ego ATE +0.5 mm); the
    rotation filter (when it runs) keeps its rotation and turn rate, less noisy than the BA's
    (objects.rotation_filter in config.py)."""
    newest = o is track.last
    R_filter, w_filter = o.T_w_o[:3, :3].copy(), o.w_o.copy()
    o.T_w_o = rigid(T_w_o)
    o.v_o, o.w_o = v_o.copy(), w_o.copy()
    if newest and track.state_mean is not None:
        track.state_mean[:3] = o.T_w_o[:3, 3]
    if newest and track.rot_cov is not None:
        o.T_w_o[:3, :3], o.w_o = R_filter, w_filter


def object_local_ba(kf: KeyFrame, map_: Map, objects: ObjectMap, weak: list[int], camera_weak: bool,
                    mapper, config: SlamConfig) -> dict[str, int]:
    """BA with objects for keyframe `kf` (module docstring); returns the parameter counts of the window
    (empty when there was nothing to optimize). `mapper`: the `LocalMapper` (camera, pyramid sigmas)."""
    tail = config.optim.objects.tail_seconds
    tracks = [objects.tracks[t] for t in weak]
    if camera_weak:
        free_ids, fixed_ids, pts = _static_window(kf, map_, config)
    else:
        free_ids = sorted({o.kf_id for t in tracks for o in t.observations
                           if o.kf_id in map_.keyframes and within(kf.timestamp - o.timestamp, tail)})
        fixed_ids, pts = [], np.zeros(0, dtype=np.int64)
    all_ids = list(free_ids) + list(fixed_ids)
    if not all_ids or not tracks:
        return {}
    window_row = np.full(max(all_ids) + 1, -1, dtype=np.int64)  # keyframe id -> row in the window
    window_row[all_ids] = np.arange(len(all_ids))
    in_window = set(all_ids)
    # Object observations in the window and their points (each object's points once).
    obs_list: list[tuple[int, ObjectObservation]] = []
    for k, tr in enumerate(tracks):
        obs_list += [(k, o) for o in tr.observations
                     if o.kf_id in in_window and within(kf.timestamp - o.timestamp, tail)]
    if not obs_list:
        return {}
    P = objects.points
    oobs_f, oobs_kp_pt = [], []
    for f, (_, o) in enumerate(obs_list):
        alive = P.alive[o.pt_ids]
        o.kp_idx, o.pt_ids = o.kp_idx[alive], o.pt_ids[alive]
        oobs_f.append(np.full(len(o.pt_ids), f))
        oobs_kp_pt.append(o.pt_ids)
    oobs_f = np.concatenate(oobs_f)
    opt_ids = np.concatenate(oobs_kp_pt)
    obj_pts, oobs_pt = np.unique(opt_ids, return_inverse=True)
    track_ids = np.array(weak, dtype=np.int64)
    track_row = np.full(track_ids.max() + 1, -1, dtype=np.int64)  # track id -> index into `tracks`
    track_row[track_ids] = np.arange(len(track_ids))
    track_of_point = track_row[P.track[obj_pts]]
    oobs_meas = np.concatenate([map_.keyframes[o.kf_id].measurements(o.kp_idx) for _, o in obs_list])
    oobs_inv_sigma2 = np.concatenate([mapper.inv_level_sigma2[map_.keyframes[o.kf_id].keypoints.octave[o.kp_idx]]
                                      for _, o in obs_list])
    # Static observations of the window keyframes (variables when camera_weak, constants otherwise).
    if not camera_weak:
        pts = map_.points_of_keyframes(all_ids)
    obs_kf, obs_pt, obs_kp = map_.observers(pts)
    keep = np.isin(obs_kf, all_ids)
    obs_kf, obs_pt, obs_kp = obs_kf[keep], obs_pt[keep], obs_kp[keep]
    meas = np.empty((len(obs_kf), 3))
    inv_sigma2 = np.empty(len(obs_kf))
    for k in np.unique(obs_kf).tolist():
        m = obs_kf == k
        meas[m] = map_.keyframes[k].measurements(obs_kp[m])
        inv_sigma2[m] = mapper.inv_level_sigma2[map_.keyframes[k].keypoints.octave[obs_kp[m]]]
    pt_index = np.full(map_.points.size, -1, dtype=np.int64)
    pt_index[pts] = np.arange(len(pts))
    problem = ObjectBAProblem(
        T_c_w=np.stack([map_.keyframes[k].T_c_w for k in all_ids]),
        fixed=np.array([False] * len(free_ids) + [True] * len(fixed_ids)),
        X_w=map_.points.X_w[pts].copy(), obs_kf=window_row[obs_kf],
        obs_pt=pt_index[obs_pt], meas=meas, inv_sigma2=inv_sigma2,
        obj_frames=window_row[[o.kf_id for _, o in obs_list]],
        obj_id=np.array([k for k, _ in obs_list]),
        T_w_o=np.stack([o.T_w_o for _, o in obs_list]),
        v_o=np.stack([o.v_o for _, o in obs_list]), w_o=np.stack([o.w_o for _, o in obs_list]),
        timestamps=np.array([map_.keyframes[k].timestamp for k in all_ids]),
        X_o=P.X_o[obj_pts].copy(), pt_obj=track_of_point,
        oobs_f=oobs_f, oobs_pt=oobs_pt, oobs_meas=oobs_meas, oobs_inv_sigma2=oobs_inv_sigma2,
        obj_measured=np.array([o.measured for _, o in obs_list]),
        optimize_static=camera_weak, optimize_objects=True,
    )
    result = object_bundle_adjustment(problem, mapper.camera, config.optim)
    if not all(np.all(np.isfinite(a)) for a in (result.T_c_w, result.X_w, result.T_w_o, result.X_o)):
        return {}
    for i, k in enumerate(free_ids):
        map_.keyframes[k].T_c_w = rigid(result.T_c_w[i])
    X_o, T_w_o, v_o = keep_object_origins(P.X_o[obj_pts], result.X_o, track_of_point, result.T_w_o, result.v_o,
                                          result.w_o, problem.obj_id)
    P.X_o[obj_pts] = X_o
    for f, (k, o) in enumerate(obs_list):
        write_back(tracks[k], o, T_w_o[f], v_o[f], result.w_o[f])
        good = result.obj_inlier[oobs_f == f]
        o.kp_idx, o.pt_ids = o.kp_idx[good], o.pt_ids[good]
    if camera_weak:
        map_.points.X_w[pts] = result.X_w
        out = np.flatnonzero(~np.asarray(result.inlier, dtype=bool))
        for k in np.unique(obs_kf[out]).tolist():
            map_.erase_observations(map_.keyframes[k], obs_kp[out][obs_kf[out] == k])
        map_.cull_points(pts[map_.points.n_obs[pts] <= 0])
        # as the static local BA: a descriptor only changes with the observations, the normals with the points
        map_.update_point_descriptors_and_normals(np.unique(obs_pt[out]), mapper.scale_factors)
        map_.update_point_descriptors_and_normals(pts, mapper.scale_factors, descriptors=False)
    return result.n_parameters
