"""Relocalization of a lost frame against the map (ORB-SLAM2's Relocalization): descriptor
matching to candidate keyframes, PnP RANSAC, pose-only optimization, projection search."""

from __future__ import annotations

import cv2
import numpy as np

from dynaslam2.features.matcher import unique_by_distance
from dynaslam2.geometry.se3 import make_pose
from dynaslam2.map.frame import Frame
from dynaslam2.map.map import Map
from dynaslam2.tracking.camera import CameraTracker, knn2_hamming


def candidate_keyframes(map_: Map, last_ref_id: int | None, n: int) -> list[int]:
    """The last reference keyframe, its covisible keyframes, then the most recent ones (ORB-SLAM2
    queries a BoW database here)."""
    ids: dict[int, None] = {}
    if last_ref_id is not None and last_ref_id in map_.keyframes:
        ids[last_ref_id] = None
        for k in map_.covisible(last_ref_id):
            ids.setdefault(k)
    for k in sorted(map_.keyframes, reverse=True):
        ids.setdefault(k)
    return list(ids)[:n]


def relocalize(frame: Frame, map_: Map, tracker: CameraTracker, last_ref_id: int | None) -> bool:
    """Try each candidate keyframe: matches -> PnP RANSAC -> optimize (+ projection search);
    success leaves the frame's pose and matches set (>= min_inliers_relocalized inliers)."""
    cfg = tracker.cfg
    cam = tracker.camera
    usable = np.flatnonzero(frame.static)
    if len(usable) < cfg.reloc_min_matches:
        return False
    desc_f = frame.keypoints.desc[usable]
    for kf_id in candidate_keyframes(map_, last_ref_id, cfg.reloc_candidates):
        kf = map_.keyframes[kf_id]
        k_kf = kf.matched()
        pt = map_.points.resolve(kf.point_ids[k_kf])
        k_kf, pt = k_kf[pt >= 0], pt[pt >= 0]
        if len(pt) < cfg.reloc_min_matches:
            continue
        best, d1, d2 = knn2_hamming(kf.keypoints.desc[k_kf], desc_f)
        ok = (best >= 0) & (d1 <= tracker.config.matcher.th_low) & (d1 < cfg.reloc_nn_ratio * d2)
        if np.count_nonzero(ok) < cfg.reloc_min_matches:
            continue
        q = np.flatnonzero(ok)
        kp_f = usable[best[q]]
        # One map point per keypoint (keep the closest descriptor).
        kp_f = unique_by_distance(kp_f, d1[q])
        sel = kp_f >= 0
        kp_f, pts = kp_f[sel], pt[q][sel]
        if len(pts) < cfg.reloc_min_matches:
            continue
        X_w = map_.points.X_w[pts].astype(np.float64)
        uv = frame.keypoints.uv[kp_f].astype(np.float64)
        found, rvec, tvec, inl = cv2.solvePnPRansac(
            X_w, uv, cam.K, None, iterationsCount=cfg.reloc_ransac_iterations,
            reprojectionError=cfg.reloc_ransac_px, confidence=0.99, flags=cv2.SOLVEPNP_EPNP,
        )
        if not found or inl is None or len(inl) < cfg.reloc_min_pnp_inliers:
            continue
        inl = inl.ravel()
        frame.T_c_w = make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
        frame.point_ids[:] = -1
        frame.point_ids[kp_f[inl]] = pts[inl]
        n = tracker.optimize(frame, map_)
        tracker.discard_outliers(frame)
        if n < cfg.reloc_min_pnp_inliers:
            continue
        if n < cfg.min_inliers_relocalized:
            tracker.search_local_points(frame, map_, [kf_id] + map_.covisible(kf_id, cfg.local_neighbours),
                                        cfg.local_radius_relocalized)
            n = tracker.optimize(frame, map_)
            tracker.discard_outliers(frame)
        if n >= cfg.min_inliers_relocalized:
            return True
    frame.point_ids[:] = -1
    return False

