"""Camera tracking against the static map (ORB-SLAM2's Tracking): motion model, reference
keyframe, local map, pose-only optimization, keyframe decision."""

from __future__ import annotations

import cv2
import numpy as np

from dynaslam2.config import SlamConfig
from dynaslam2.features.matcher import rotation_consistent, search_by_projection, unique_by_distance
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.map.frame import Frame
from dynaslam2.map.keyframe import KeyFrame
from dynaslam2.map.map import Map
from dynaslam2.optim.pose_only import optimize_pose


def transform_points(T: np.ndarray, X: np.ndarray) -> np.ndarray:
    return X @ T[:3, :3].T + T[:3, 3]


def rigid(T: np.ndarray) -> np.ndarray:
    """The nearest rigid transform (rotation projected onto SO(3) by SVD): keeps round-off from
    compounding through velocity products and inverses."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = T[:3, 3]
    return out


def predicted_levels(dist: np.ndarray, max_dist: np.ndarray, log_scale: float, n_levels: int) -> np.ndarray:
    """Pyramid level at which a point at `dist` is expected (ORB-SLAM2's PredictScale)."""
    ratio = max_dist / np.maximum(dist, 1e-9)
    return np.clip(np.ceil(np.log(np.maximum(ratio, 1e-9)) / log_scale), 0, n_levels - 1).astype(np.int64)


def knn2_hamming(desc_q: np.ndarray, desc_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each query descriptor: best train index, best and second-best Hamming distance
    (OpenCV's brute-force matcher; second = 256 when there is one train descriptor)."""
    n = len(desc_q)
    best = np.full(n, -1, dtype=np.int64)
    d1 = np.full(n, 256, dtype=np.int64)
    d2 = np.full(n, 256, dtype=np.int64)
    if n == 0 or len(desc_t) == 0:
        return best, d1, d2
    matches = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(desc_q, desc_t, k=2)
    # Unpack OpenCV's DMatch lists (one per query) into arrays.
    flat = np.fromiter((v for ms in matches for v in (ms[0].queryIdx, ms[0].trainIdx, ms[0].distance,
                                                     ms[1].distance if len(ms) > 1 else 256)),
                       dtype=np.float64).reshape(-1, 4)
    q = flat[:, 0].astype(np.int64)
    best[q], d1[q], d2[q] = flat[:, 1].astype(np.int64), flat[:, 2].astype(np.int64), flat[:, 3].astype(np.int64)
    return best, d1, d2


class CameraTracker:
    """Algorithms that estimate a frame's `T_c_w` from the map (state lives in `Frame` and `Map`)."""

    def __init__(self, config: SlamConfig, camera: StereoCamera, scale_factors: np.ndarray,
                 inv_level_sigma2: np.ndarray) -> None:
        self.config = config
        self.cfg = config.tracking
        self.camera = camera
        self.scale_factors = np.asarray(scale_factors, dtype=np.float64)
        self.inv_level_sigma2 = np.asarray(inv_level_sigma2, dtype=np.float64)
        self.n_levels = len(self.scale_factors)
        self.log_scale = float(np.log(self.scale_factors[1])) if self.n_levels > 1 else 1.0

    # ------------------------------------------------------------ pose optimization
    def optimize(self, frame: Frame, map_: Map) -> int:
        """Pose-only optimization over the frame's map matches; marks outliers; returns inliers."""
        idx = np.flatnonzero(frame.point_ids >= 0)
        frame.outlier[:] = False
        if len(idx) < 3:
            return 0
        X_w = map_.points.X_w[frame.point_ids[idx]]
        meas = frame.measurements(idx)
        inv_sigma2 = self.inv_level_sigma2[frame.keypoints.octave[idx]]
        T_c_w, inliers = optimize_pose(frame.T_c_w, X_w, meas, inv_sigma2, self.camera, self.config.optim)
        if not np.all(np.isfinite(T_c_w)):
            return 0
        frame.T_c_w = rigid(T_c_w)
        frame.outlier[idx] = ~np.asarray(inliers, dtype=bool)
        return int(np.count_nonzero(inliers))

    def discard_outliers(self, frame: Frame) -> None:
        frame.point_ids[frame.outlier] = -1
        frame.outlier[:] = False

    def n_map_matches(self, frame: Frame, map_: Map) -> int:
        ids = frame.point_ids[frame.tracked_mask()]
        return int(np.count_nonzero(map_.points.n_obs[ids] > 0))

    # ------------------------------------------------------------------ projection
    def _project(self, X_w: np.ndarray, T_c_w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        X_c = transform_points(T_c_w, X_w)
        z = X_c[:, 2]
        safe = np.where(z > 1e-6, z, 1.0)
        u = self.camera.fx * X_c[:, 0] / safe + self.camera.cx
        v = self.camera.fy * X_c[:, 1] / safe + self.camera.cy
        u_r = u - self.camera.bf / safe
        return np.column_stack([u, v]), u_r, z

    def search_last_frame(self, frame: Frame, last: Frame, map_: Map, radius: float) -> int:
        """Project the last frame's tracked points into `frame` (ORB-SLAM2's SearchByProjection
        frame-to-frame); the octave window follows the forward/backward motion."""
        k_last = np.flatnonzero(last.tracked_mask())
        pt = map_.points.resolve(last.point_ids[k_last])
        ok = pt >= 0
        k_last, pt = k_last[ok], pt[ok]
        if len(pt) == 0:
            return 0
        uv, u_r, z = self._project(map_.points.X_w[pt], frame.T_c_w)
        vis = (z > 0) & self.camera.in_image(uv)
        k_last, pt, uv, u_r = k_last[vis], pt[vis], uv[vis], u_r[vis]
        T_c_l = frame.T_c_w @ last.T_w_c
        t_l_c = -(T_c_l[:3, :3].T @ T_c_l[:3, 3])
        forward = t_l_c[2] > self.camera.baseline
        backward = -t_l_c[2] > self.camera.baseline
        o = last.keypoints.octave[k_last].astype(np.int64)
        if forward:
            rng = np.column_stack([o, np.full_like(o, self.n_levels - 1)])
        elif backward:
            rng = np.column_stack([np.zeros_like(o), o])
        else:
            rng = np.column_stack([o - 1, o + 1])
        rad = radius * self.scale_factors[o]
        free = frame.point_ids < 0
        match = search_by_projection(
            frame.keypoints, uv, map_.points.desc[pt], rad, rng, u_r, frame.u_right, self.config.matcher.th_high,
            self.cfg.motion_nn_ratio, True, angle_proj=last.keypoints.angle[k_last], available=free & frame.static,
        )
        m = match >= 0
        frame.point_ids[match[m]] = pt[m]
        return int(np.count_nonzero(m))

    def track_with_motion_model(self, frame: Frame, last: Frame, map_: Map, T_c_w_pred: np.ndarray) -> int:
        """Constant-velocity prediction + projection search (radius doubled on failure) + pose-only."""
        frame.T_c_w = T_c_w_pred.copy()
        frame.point_ids[:] = -1
        n = self.search_last_frame(frame, last, map_, self.cfg.motion_radius)
        if n < self.cfg.motion_min_matches:
            frame.point_ids[:] = -1
            n = self.search_last_frame(frame, last, map_, 2.0 * self.cfg.motion_radius)
        if n < self.cfg.motion_min_matches:
            return 0
        self.optimize(frame, map_)
        self.discard_outliers(frame)
        return self.n_map_matches(frame, map_)

    def track_reference_keyframe(self, frame: Frame, ref: KeyFrame, map_: Map, T_c_w_init: np.ndarray) -> int:
        """Brute-force descriptor matching of the frame to the reference keyframe's points with the
        ratio test and rotation consistency (ORB-SLAM2 uses BoW here), then pose-only optimization
        from the last pose."""
        frame.T_c_w = T_c_w_init.copy()
        frame.point_ids[:] = -1
        k_ref = ref.matched()
        pt = map_.points.resolve(ref.point_ids[k_ref])
        k_ref, pt = k_ref[pt >= 0], pt[pt >= 0]
        usable = np.flatnonzero(frame.static)
        if len(pt) < self.cfg.ref_min_matches or len(usable) < self.cfg.ref_min_matches:
            return 0
        best, d1, d2 = knn2_hamming(ref.keypoints.desc[k_ref], frame.keypoints.desc[usable])
        ok = (best >= 0) & (d1 <= self.config.matcher.th_low) & (d1 < self.cfg.ref_nn_ratio * d2)
        q = np.flatnonzero(ok)
        kp_f = unique_by_distance(usable[best[q]], d1[q])
        q, kp_f = q[kp_f >= 0], kp_f[kp_f >= 0]
        rot = ref.keypoints.angle[k_ref[q]].astype(np.float64) - frame.keypoints.angle[kp_f]
        cons = rotation_consistent(rot)
        q, kp_f = q[cons], kp_f[cons]
        if len(q) < self.cfg.ref_min_matches:
            return 0
        frame.point_ids[kp_f] = pt[q]
        self.optimize(frame, map_)
        self.discard_outliers(frame)
        return self.n_map_matches(frame, map_)

    # ------------------------------------------------------------------ local map
    def local_keyframes(self, frame: Frame, map_: Map) -> tuple[list[int], int | None]:
        """Keyframes observing the frame's points (by votes) plus their best covisible neighbours
        (ORB-SLAM2's UpdateLocalKeyFrames); returns (ids, reference keyframe id)."""
        ids = frame.point_ids[frame.point_ids >= 0]
        ids = ids[map_.points.alive[ids]]
        if len(ids) == 0:
            return [], None
        kf_of_obs, _, _ = map_.observers(ids)
        votes_kf, votes = np.unique(kf_of_obs, return_counts=True)
        if len(votes_kf) == 0:
            return [], None
        order = np.lexsort((votes_kf, -votes))
        first = [int(k) for k in votes_kf[order][: self.cfg.local_max_keyframes]]
        ref_id = first[0]
        chosen = dict.fromkeys(first)
        for k in first:
            if len(chosen) >= self.cfg.local_max_keyframes:
                break
            for n in map_.covisible(k, self.cfg.local_neighbours):
                if n not in chosen:
                    chosen[n] = None
                    break
        return list(chosen)[: self.cfg.local_max_keyframes], ref_id

    def search_local_points(self, frame: Frame, map_: Map, local_kfs: list[int], radius_factor: float) -> int:
        """Project the local map points not yet matched into the frame and match them
        (ORB-SLAM2's SearchLocalPoints with isInFrustum); updates visibility counters."""
        pts = map_.points_of_keyframes(local_kfs)
        matched = frame.point_ids[frame.point_ids >= 0]
        map_.points.n_visible[matched[map_.points.alive[matched]]] += 1
        map_.points.last_frame_seen[matched] = frame.index
        pts = pts[map_.points.last_frame_seen[pts] != frame.index]
        if len(pts) == 0:
            return 0
        P = map_.points
        uv, u_r, z = self._project(P.X_w[pts], frame.T_c_w)
        center = frame.center_w
        ray = P.X_w[pts] - center
        dist = np.linalg.norm(ray, axis=1)
        view_cos = np.einsum("ij,ij->i", ray, P.normal[pts]) / np.maximum(dist, 1e-9)
        vis = ((z > 0) & self.camera.in_image(uv) & (dist >= 0.8 * P.min_dist[pts])
               & (dist <= 1.2 * P.max_dist[pts]) & (view_cos >= self.cfg.view_cos_limit))
        pts, uv, u_r, dist, view_cos = pts[vis], uv[vis], u_r[vis], dist[vis], view_cos[vis]
        if len(pts) == 0:
            return 0
        P.n_visible[pts] += 1
        level = predicted_levels(dist, P.max_dist[pts], self.log_scale, self.n_levels)
        # ORB-SLAM2's RadiusByViewingCos: a tighter window when seen head-on.
        rad = radius_factor * np.where(view_cos > 0.998, 2.5, 4.0) * self.scale_factors[level]
        rng = np.column_stack([level - 1, level])
        match = search_by_projection(
            frame.keypoints, uv, P.desc[pts], rad, rng, u_r, frame.u_right, self.config.matcher.th_high,
            self.cfg.local_nn_ratio, False, available=(frame.point_ids < 0) & frame.static,
        )
        m = match >= 0
        frame.point_ids[match[m]] = pts[m]
        return int(np.count_nonzero(m))

    def track_local_map(self, frame: Frame, map_: Map, just_relocalized: bool) -> tuple[int, int | None]:
        """Local-map tracking: more matches from covisible keyframes, optimize again; returns
        (inliers, reference keyframe id) and updates found counters."""
        local_kfs, ref_id = self.local_keyframes(frame, map_)
        radius = self.cfg.local_radius_relocalized if just_relocalized else self.cfg.local_radius
        self.search_local_points(frame, map_, local_kfs, radius)
        self.optimize(frame, map_)
        tracked = frame.tracked_mask()
        ids = frame.point_ids[tracked]
        map_.points.n_found[ids] += 1
        inliers = int(np.count_nonzero(map_.points.n_obs[ids] > 0))
        frame.point_ids[frame.outlier] = -1
        return inliers, ref_id

    # ---------------------------------------------------------------- keyframes
    def need_new_keyframe(self, frame: Frame, map_: Map, ref: KeyFrame, n_inliers: int,
                          frames_since_kf: int, frames_since_reloc: int) -> bool:
        """ORB-SLAM2's NeedNewKeyFrame for stereo/RGB-D, with local mapping always idle (one process)."""
        cfg = self.cfg
        n_kfs = len(map_)
        if frames_since_reloc < cfg.max_frames and n_kfs > cfg.max_frames:
            return False
        min_obs = 3 if n_kfs > 2 else 2
        ref_ids = ref.point_ids[ref.point_ids >= 0]
        n_ref_matches = int(np.count_nonzero(map_.points.alive[ref_ids] & (map_.points.n_obs[ref_ids] >= min_obs)))
        close = (frame.depth > 0) & (frame.depth < frame.th_depth) & frame.static
        tracked = frame.tracked_mask()
        n_tracked_close = int(np.count_nonzero(close & tracked))
        n_untracked_close = int(np.count_nonzero(close & ~tracked))
        need_close = n_tracked_close < cfg.close_tracked_max and n_untracked_close > cfg.close_untracked_min
        th_ref_ratio = cfg.ref_ratio if n_kfs >= 2 else 0.4
        c1a = frames_since_kf >= cfg.max_frames
        c1b = frames_since_kf >= cfg.min_frames
        c1c = n_inliers < n_ref_matches * cfg.ref_ratio_stereo_force or need_close
        c2 = (n_inliers < n_ref_matches * th_ref_ratio or need_close) and n_inliers > cfg.keyframe_min_inliers
        return bool((c1a or c1b or c1c) and c2)
