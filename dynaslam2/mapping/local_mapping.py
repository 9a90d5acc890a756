"""Keyframe insertion and local mapping (ORB-SLAM2's CreateNewKeyFrame and LocalMapping), run inline
after tracking in one process: new points, map-point culling, triangulation with neighbours, fusion
of duplicates, local bundle adjustment over the covisible window, keyframe culling."""

from __future__ import annotations

import time

import numpy as np

from dynaslam2.config import SlamConfig
from dynaslam2.features.matcher import (
    hamming_pairs_within, rotation_consistent, search_by_projection, unique_by_distance,
)
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import hat
from dynaslam2.map.frame import Frame
from dynaslam2.map.keyframe import KeyFrame
from dynaslam2.map.map import Map
from dynaslam2.optim.local_ba import BAProblem, StereoFactorCache, local_bundle_adjustment
from dynaslam2.tracking.camera import predicted_levels, rigid, transform_points


def _pencil_windows(x1: np.ndarray, x2: np.ndarray, K: np.ndarray, T_2_1: np.ndarray, th2: np.ndarray):
    """Candidate pairs of `epipolar_pairs` without the dense N1 x N2 test: every epipolar line passes
    through the epipole, so lines are angles phi of that pencil (in normalized coordinates); each
    keypoint j of image 2 gets the window of angles whose lines can pass within its threshold.
    Returns (F21, a, b): the fundamental matrix and the candidate pairs, grouped by b."""
    K_inv = np.linalg.inv(K)
    F21 = K_inv.T @ hat(T_2_1[:3, 3]) @ T_2_1[:3, :3] @ K_inv
    E21 = hat(T_2_1[:3, 3]) @ T_2_1[:3, :3]
    x1n, x2n = x1 @ K_inv.T, x2 @ K_inv.T
    e = T_2_1[:3, 3] / np.linalg.norm(T_2_1[:3, 3])  # epipole in normalized coordinates
    a_vec = np.cross(e, np.eye(3)[int(np.argmin(np.abs(e)))])
    a_vec /= np.linalg.norm(a_vec)
    b_vec = np.cross(e, a_vec)
    L1n = x1n @ E21.T  # normalized epipolar lines, all through e
    phi1 = np.mod(np.arctan2(L1n @ b_vec, L1n @ a_vec), np.pi)
    L2n = np.cross(e[None, :], x2n)  # line through e and each image-2 keypoint
    phi2 = np.mod(np.arctan2(L2n @ b_vec, L2n @ a_vec), np.pi)
    # Distance of x2n to the pencil line at phi2 + d is |sin d| |l'(phi2).x2n| / |l(phi2 + d)[:2]| and
    # |l[:2]| <= m (largest singular value of [a b][:2]): this window cannot miss a pair.
    c, s_ = np.cos(phi2), np.sin(phi2)
    dl_phi = -s_[:, None] * a_vec + c[:, None] * b_vec
    m = np.linalg.norm(np.column_stack([a_vec[:2], b_vec[:2]]), 2)
    th_n = np.sqrt(th2) / min(K[0, 0], K[1, 1])
    ratio = th_n * m / np.maximum(np.abs(np.einsum("ij,ij->i", dl_phi, x2n)), 1e-12)
    # Windows shorter than pi hold each image-1 keypoint once among the three shifted copies.
    half = np.minimum(np.arcsin(np.minimum(ratio, 1.0)), np.pi / 2 - 1e-9)
    order = np.argsort(phi1, kind="stable")
    phi_sorted = np.concatenate([phi1[order] - np.pi, phi1[order], phi1[order] + np.pi])
    lo = np.searchsorted(phi_sorted, phi2 - half, side="left")
    hi = np.searchsorted(phi_sorted, phi2 + half, side="right")
    count = hi - lo
    # Pair k of keypoint j reads position lo[j] + (k - first pair of j) of the sorted copies.
    pos = np.arange(int(count.sum())) + np.repeat(lo - (np.cumsum(count) - count), count)
    return F21, np.tile(order, 3)[pos], np.repeat(np.arange(len(x2)), count)


def _near_epipolar_line(x1: np.ndarray, x2: np.ndarray, F21: np.ndarray, th2: np.ndarray,
                        a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Exact test in pixels (ORB-SLAM2's CheckDistEpipolarLine) of the pairs (a, b)."""
    L1 = x1 @ F21.T
    num = np.einsum("ij,ij->i", L1[a], x2[b])
    return num**2 < th2[b] * (L1[a, 0] ** 2 + L1[a, 1] ** 2)


def epipolar_pairs(x1: np.ndarray, x2: np.ndarray, K: np.ndarray, T_2_1: np.ndarray,
                   th2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j) with keypoint j of image 2 within sqrt(th2[j]) px of the epipolar line of keypoint
    i of image 1 (ORB-SLAM2's CheckDistEpipolarLine), without the dense N1 x N2 test (candidates of
    `_pencil_windows`, then the exact test). x1, x2: (N, 3) homogeneous pixels."""
    F21, a, b = _pencil_windows(x1, x2, K, T_2_1, th2)
    ok = _near_epipolar_line(x1, x2, F21, th2, a, b)
    return a[ok], b[ok]


def epipolar_matches(x1: np.ndarray, x2: np.ndarray, K: np.ndarray, T_2_1: np.ndarray, th2: np.ndarray,
                     desc1: np.ndarray, desc2: np.ndarray, max_dist: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs of `epipolar_pairs` whose descriptors (desc1 of x1, desc2 of x2) are within `max_dist`
    Hamming distance, and those distances. The descriptor test runs first: it keeps ~0.05% of the
    candidates at ORB-SLAM2's TH_LOW, so the exact line test only sees those."""
    F21, a, b = _pencil_windows(x1, x2, K, T_2_1, th2)
    k, dist = hamming_pairs_within(desc1, desc2, a, b, max_dist)
    a, b = a[k], b[k]
    ok = _near_epipolar_line(x1, x2, F21, th2, a, b)
    return a[ok], b[ok], dist[ok]


class LocalMapper:
    """Builds and refines the map around each new keyframe (state lives in `Map`)."""

    def __init__(self, config: SlamConfig, camera: StereoCamera, scale_factors: np.ndarray) -> None:
        self.config = config
        self.cfg = config.mapping
        self.camera = camera
        self.scale_factors = np.asarray(scale_factors, dtype=np.float64)
        self.level_sigma2 = self.scale_factors**2
        self.inv_level_sigma2 = 1.0 / self.level_sigma2
        self.n_levels = len(self.scale_factors)
        self.log_scale = float(np.log(self.scale_factors[1])) if self.n_levels > 1 else 1.0
        self.recent_points = np.zeros(0, dtype=np.int64)
        self.next_kf_id = 0
        self.ba_factors = StereoFactorCache()  # the last local BA window's stereo factors (gtsam solver)

    def reset(self) -> None:
        """Forget per-map state (a new map segment)."""
        self.recent_points = np.zeros(0, dtype=np.int64)
        self.ba_factors = StereoFactorCache()

    # --------------------------------------------------------------- insertion
    def create_keyframe(self, frame: Frame, map_: Map, new_points_min: int) -> KeyFrame:
        """Insert `frame` as a keyframe: its tracked points become observations and its close
        stereo points new map points (ORB-SLAM2's CreateNewKeyFrame / StereoInitialization)."""
        kf = KeyFrame.from_frame(self.next_kf_id, frame, segment=map_.segment)
        self.next_kf_id += 1
        map_.add_keyframe(kf)
        tracked = np.flatnonzero(frame.tracked_mask())
        pts = map_.points.resolve(frame.point_ids[tracked])
        ok = pts >= 0
        tracked, pts = tracked[ok], pts[ok]
        _, first = np.unique(pts, return_index=True)
        map_.add_observations(kf, tracked[first], pts[first])
        # New points from stereo: closest first; all close ones, at least `new_points_min` in total.
        cand = np.flatnonzero((frame.depth > 0) & frame.static)
        cand = cand[np.argsort(frame.depth[cand], kind="stable")]
        keep = (frame.depth[cand] <= frame.th_depth) | (np.arange(len(cand)) < new_points_min)
        cand = cand[keep]
        new = cand[kf.point_ids[cand] < 0]
        if len(new):
            ids = map_.add_points(kf, new, kf.unproject(new, self.camera))
            frame.point_ids[new] = ids
            frame.outlier[new] = False
            self.recent_points = np.concatenate([self.recent_points, ids])
        return kf

    # ----------------------------------------------------------- local mapping
    def process(self, kf: KeyFrame, map_: Map, static_ba: bool = True, triangulate: bool = True) -> dict[str, float]:
        """Local mapping for a new keyframe; returns a breakdown in ms. `static_ba=False` leaves the
        BA to the caller (BA with objects, `mapping.objects.object_local_ba`); `triangulate=False`: no new
        static points from matches with the neighbours (a keyframe inserted for an object only, III-D)."""
        detail = {}
        t = time.perf_counter()

        def lap(name: str) -> None:
            nonlocal t
            now = time.perf_counter()
            detail[name] = (now - t) * 1e3
            t = now

        map_.update_point_descriptors_and_normals(kf.point_ids[kf.matched()], self.scale_factors)
        map_.update_connections(kf, self.cfg.covisibility_min_weight)
        self.cull_recent_points(kf, map_)
        lap("process")
        if triangulate:
            self.triangulate(kf, map_)
        lap("triangulation")
        self.fuse_neighbours(kf, map_)
        lap("fusion")
        if static_ba:
            self.local_ba(kf, map_)
        lap("ba")
        self.cull_keyframes(kf, map_)
        lap("kf_culling")
        return detail

    def cull_recent_points(self, kf: KeyFrame, map_: Map) -> None:
        """ORB-SLAM2's MapPointCulling on recently created points."""
        P = map_.points
        ids = self.recent_points
        ids = ids[P.alive[ids]]
        age = kf.id - P.first_kf[ids]
        bad = (P.found_ratio(ids) < self.cfg.cull_found_ratio) | (
            (age >= self.cfg.cull_after_keyframes) & (P.n_obs[ids] <= self.cfg.cull_obs_threshold))
        map_.cull_points(ids[bad])
        self.recent_points = ids[~bad & (age < self.cfg.cull_after_keyframes + 1)]

    # ------------------------------------------------------------ triangulation
    def triangulate(self, kf1: KeyFrame, map_: Map) -> int:
        """New points from matches with the best covisible keyframes (ORB-SLAM2's
        CreateNewMapPoints): epipolar-constrained descriptor matching of unmatched keypoints,
        linear triangulation or stereo back-projection, then depth, reprojection and scale checks."""
        cam = self.camera
        created = 0
        C1 = kf1.center_w
        for kf2_id in map_.covisible(kf1.id, self.cfg.triangulation_neighbours):
            kf2 = map_.keyframes[kf2_id]
            C2 = kf2.center_w
            if np.linalg.norm(C2 - C1) < cam.baseline:
                continue
            i1 = np.flatnonzero((kf1.point_ids < 0) & kf1.static)
            i2 = np.flatnonzero((kf2.point_ids < 0) & kf2.static)
            if len(i1) == 0 or len(i2) == 0:
                continue
            T_2_1 = kf2.T_c_w @ kf1.T_w_c
            x1 = np.column_stack([kf1.keypoints.uv[i1].astype(np.float64), np.ones(len(i1))])
            x2 = np.column_stack([kf2.keypoints.uv[i2].astype(np.float64), np.ones(len(i2))])
            th2 = 3.84 * self.level_sigma2[kf2.keypoints.octave[i2]]
            a, b, dist = epipolar_matches(x1, x2, cam.K, T_2_1, th2, kf1.keypoints.desc[i1],
                                          kf2.keypoints.desc[i2], self.config.matcher.th_low)
            if len(a) == 0:
                continue
            order = np.lexsort((b, dist, a))
            a, b, dist = a[order], b[order], dist[order]
            first = np.r_[True, a[1:] != a[:-1]]
            a, b, dist = a[first], b[first], dist[first]
            match = unique_by_distance(b, dist)
            sel = match >= 0
            j1, j2 = i1[a[sel]], i2[match[sel]]
            rot = kf1.keypoints.angle[j1].astype(np.float64) - kf2.keypoints.angle[j2]
            cons = rotation_consistent(rot)
            j1, j2 = j1[cons], j2[cons]
            if len(j1) == 0:
                continue
            X_w, good = self._triangulate_pairs(kf1, kf2, j1, j2)
            j1, j2, X_w = j1[good], j2[good], X_w[good]
            if len(j1) == 0:
                continue
            ids = map_.add_points(kf1, j1, X_w)
            map_.add_observations(kf2, j2, ids)
            self.recent_points = np.concatenate([self.recent_points, ids])
            created += len(ids)
        return created

    def _triangulate_pairs(self, kf1: KeyFrame, kf2: KeyFrame, j1: np.ndarray, j2: np.ndarray):
        """Vectorized body of ORB-SLAM2's CreateNewMapPoints for matched keypoint pairs."""
        cam = self.camera
        K_inv = np.linalg.inv(cam.K)
        uv1 = kf1.keypoints.uv[j1].astype(np.float64)
        uv2 = kf2.keypoints.uv[j2].astype(np.float64)
        xn1 = np.column_stack([uv1, np.ones(len(j1))]) @ K_inv.T
        xn2 = np.column_stack([uv2, np.ones(len(j2))]) @ K_inv.T
        R_w_1, R_w_2 = kf1.T_w_c[:3, :3], kf2.T_w_c[:3, :3]
        ray1, ray2 = xn1 @ R_w_1.T, xn2 @ R_w_2.T
        cos_rays = np.einsum("ij,ij->i", ray1, ray2) / (np.linalg.norm(ray1, axis=1) * np.linalg.norm(ray2, axis=1))
        d1, d2 = kf1.depth[j1], kf2.depth[j2]
        st1, st2 = d1 > 0, d2 > 0
        cos_st1 = np.where(st1, np.cos(2 * np.arctan2(cam.baseline / 2, np.where(st1, d1, 1.0))), cos_rays + 1)
        cos_st2 = np.where(st2, np.cos(2 * np.arctan2(cam.baseline / 2, np.where(st2, d2, 1.0))), cos_rays + 1)
        cos_st = np.minimum(cos_st1, cos_st2)
        use_dlt = (cos_rays < cos_st) & (cos_rays > 0) & (st1 | st2 | (cos_rays < self.cfg.triangulation_min_parallax_cos))
        use_1 = ~use_dlt & st1 & (cos_st1 < cos_st2)
        use_2 = ~use_dlt & ~use_1 & st2 & (cos_st2 < cos_st1)
        X_w = np.zeros((len(j1), 3))
        valid = use_dlt | use_1 | use_2
        if use_dlt.any():
            P1, P2 = kf1.T_c_w[:3], kf2.T_c_w[:3]
            m = np.flatnonzero(use_dlt)
            A = np.stack([
                xn1[m, 0:1] * P1[2] - P1[0], xn1[m, 1:2] * P1[2] - P1[1],
                xn2[m, 0:1] * P2[2] - P2[0], xn2[m, 1:2] * P2[2] - P2[1],
            ], axis=1)
            _, _, vt = np.linalg.svd(A)
            h = vt[:, -1]
            nz = np.abs(h[:, 3]) > 1e-12
            X_w[m[nz]] = h[nz, :3] / h[nz, 3:4]
            valid[m[~nz]] = False
        if use_1.any():
            X_w[use_1] = kf1.unproject(j1[use_1], cam)
        if use_2.any():
            X_w[use_2] = kf2.unproject(j2[use_2], cam)
        ok = valid.copy()
        for kf, j in ((kf1, j1), (kf2, j2)):
            X_c = transform_points(kf.T_c_w, X_w)
            z = X_c[:, 2]
            ok &= z > 0
            zs = np.where(z > 0, z, 1.0)
            u = cam.fx * X_c[:, 0] / zs + cam.cx
            v = cam.fy * X_c[:, 1] / zs + cam.cy
            uv = kf.keypoints.uv[j].astype(np.float64)
            e2 = (u - uv[:, 0]) ** 2 + (v - uv[:, 1]) ** 2
            stereo = kf.u_right[j] >= 0
            e2 = e2 + np.where(stereo, (u - cam.bf / zs - kf.u_right[j]) ** 2, 0.0)
            sigma2 = self.level_sigma2[kf.keypoints.octave[j]]
            th = np.where(stereo, self.config.optim.chi2_stereo, self.config.optim.chi2_mono)
            ok &= e2 <= th * sigma2
        dist1 = np.linalg.norm(X_w - kf1.center_w, axis=1)
        dist2 = np.linalg.norm(X_w - kf2.center_w, axis=1)
        ok &= (dist1 > 0) & (dist2 > 0)
        ratio_dist = dist2 / np.maximum(dist1, 1e-12)
        ratio_octave = self.scale_factors[kf1.keypoints.octave[j1]] / self.scale_factors[kf2.keypoints.octave[j2]]
        factor = 1.5 * self.scale_factors[1] if self.n_levels > 1 else 1.5
        ok &= ~((ratio_dist * factor < ratio_octave) | (ratio_dist > ratio_octave * factor))
        return X_w, ok

    # ------------------------------------------------------------------- fusion
    def fuse(self, kf: KeyFrame, pt_ids: np.ndarray, map_: Map) -> None:
        """Project points into `kf` and merge with what it sees (ORB-SLAM2's ORBmatcher::Fuse):
        a free keypoint gains the observation; a keypoint with another point keeps the point with
        more observations."""
        P = map_.points
        pts = P.resolve(pt_ids)
        mark = np.zeros(P.size, dtype=bool)  # a mark per point id: sorted unique ids without a sort
        mark[pts[pts >= 0]] = True
        mark[kf.point_ids[kf.point_ids >= 0]] = False  # not those the keyframe already has
        pts = np.flatnonzero(mark)
        if len(pts) == 0:
            return
        cam = self.camera
        X_c = transform_points(kf.T_c_w, P.X_w[pts])
        z = X_c[:, 2]
        zs = np.where(z > 0, z, 1.0)
        uv = np.column_stack([cam.fx * X_c[:, 0] / zs + cam.cx, cam.fy * X_c[:, 1] / zs + cam.cy])
        u_r = uv[:, 0] - cam.bf / zs
        ray = P.X_w[pts] - kf.center_w
        dist = np.linalg.norm(ray, axis=1)
        vis = ((z > 0) & cam.in_image(uv) & (dist >= 0.8 * P.min_dist[pts]) & (dist <= 1.2 * P.max_dist[pts])
               & (np.einsum("ij,ij->i", ray, P.normal[pts]) >= 0.5 * dist))
        pts, uv, u_r, dist = pts[vis], uv[vis], u_r[vis], dist[vis]
        if len(pts) == 0:
            return
        level = predicted_levels(dist, P.max_dist[pts], self.log_scale, self.n_levels)
        rad = self.cfg.fuse_radius * self.scale_factors[level]
        match = search_by_projection(
            kf.keypoints, uv, P.desc[pts], rad, np.column_stack([level - 1, level]), u_r, kf.u_right,
            self.config.matcher.th_low, 1.0, False, available=kf.static,
        )
        m = np.flatnonzero(match >= 0)
        if len(m) == 0:
            return
        j = match[m].astype(np.int64)
        # Reprojection check with the keypoint's scale (ORB-SLAM2 Fuse's chi2 test).
        kuv = kf.keypoints.uv[j].astype(np.float64)
        e2 = ((uv[m] - kuv) ** 2).sum(1)
        stereo = kf.u_right[j] >= 0
        e2 = e2 + np.where(stereo, (u_r[m] - kf.u_right[j]) ** 2, 0.0)
        th = np.where(stereo, self.config.optim.chi2_stereo, self.config.optim.chi2_mono)
        good = e2 * self.inv_level_sigma2[kf.keypoints.octave[j]] <= th
        m, j = m[good], j[good]
        p = pts[m]
        q = kf.point_ids[j]
        has = q >= 0
        has_alive = has.copy()
        has_alive[has] = P.alive[q[has]]
        # Replace the point with fewer observations by the other.
        pa, qa = p[has_alive], q[has_alive]
        keep_q = P.n_obs[qa] > P.n_obs[pa]
        old = np.where(keep_q, pa, qa)
        new = np.where(keep_q, qa, pa)
        free = ~has
        map_.add_observations(kf, j[free], p[free])
        map_.replace_points(old, new)

    def fuse_neighbours(self, kf: KeyFrame, map_: Map) -> None:
        """ORB-SLAM2's SearchInNeighbors: fuse the keyframe's points into first- and second-order
        neighbours, and theirs into it; then refresh descriptors, normals and connections."""
        targets: dict[int, None] = {}
        for n in map_.covisible(kf.id, self.cfg.fuse_neighbours):
            targets.setdefault(n)
            for n2 in map_.covisible(n, self.cfg.fuse_second_neighbours):
                if n2 != kf.id:
                    targets.setdefault(n2)
        targets.pop(kf.id, None)
        if not targets:
            return
        own = kf.point_ids[kf.point_ids >= 0]
        for t in targets:
            self.fuse(map_.keyframes[t], own, map_)
        theirs = map_.points_of_keyframes(list(targets))
        self.fuse(kf, theirs, map_)
        map_.update_point_descriptors_and_normals(kf.point_ids[kf.point_ids >= 0], self.scale_factors)
        map_.update_connections(kf, self.cfg.covisibility_min_weight)

    # ---------------------------------------------------------------- local BA
    def local_ba(self, kf: KeyFrame, map_: Map) -> None:
        """Local BA over `kf` and its covisible keyframes; keyframes that see the local points but
        are not local stay fixed (ORB-SLAM2's LocalBundleAdjustment). Outlier observations are erased."""
        local = [kf.id] + map_.covisible(kf.id, self.cfg.ba_max_keyframes - 1)
        pts = map_.points_of_keyframes(local)
        if len(pts) == 0:
            return
        obs_kf, obs_pt, obs_kp = map_.observers(pts)
        local_set = set(local)
        # Fixed: the keyframes outside the window that see the most local points.
        outside = ~np.isin(obs_kf, local)
        ids_out, counts = np.unique(obs_kf[outside], return_counts=True)
        order = np.lexsort((ids_out, -counts))[: self.cfg.ba_max_fixed_keyframes]
        fixed_ids = sorted(ids_out[order].tolist())
        keep = np.isin(obs_kf, local + fixed_ids)
        obs_kf, obs_pt, obs_kp = obs_kf[keep], obs_pt[keep], obs_kp[keep]
        # A point seen by one keyframe does not constrain any pose: leave it out of the problem.
        n_views = np.bincount(obs_pt, minlength=map_.points.size)
        multi = n_views[obs_pt] >= self.cfg.ba_min_views
        obs_kf, obs_pt, obs_kp = obs_kf[multi], obs_pt[multi], obs_kp[multi]
        pts = pts[n_views[pts] >= self.cfg.ba_min_views]
        if len(pts) == 0:
            return
        all_ids = sorted(local + fixed_ids)  # increasing ids: the BA's stable keys (factor cache)
        fixed = np.isin(all_ids, fixed_ids)
        first_id = min(map_.keyframes)
        if first_id in local_set:
            fixed[all_ids.index(first_id)] = True
        if not fixed.any():
            fixed[all_ids.index(min(local))] = True
        if fixed.all():
            return
        kf_index = np.full(max(all_ids) + 1, -1, dtype=np.int64)
        kf_index[all_ids] = np.arange(len(all_ids))
        pt_index = np.full(map_.points.size, -1, dtype=np.int64)
        pt_index[pts] = np.arange(len(pts))
        meas = np.empty((len(obs_kf), 3))
        inv_sigma2 = np.empty(len(obs_kf))
        for k in np.unique(obs_kf):
            m = obs_kf == k
            other = map_.keyframes[int(k)]
            meas[m] = other.measurements(obs_kp[m])
            inv_sigma2[m] = self.inv_level_sigma2[other.keypoints.octave[obs_kp[m]]]
        problem = BAProblem(
            T_c_w=np.stack([map_.keyframes[k].T_c_w for k in all_ids]), fixed=fixed,
            X_w=map_.points.X_w[pts].copy(), obs_kf=kf_index[obs_kf], obs_pt=pt_index[obs_pt],
            meas=meas, inv_sigma2=inv_sigma2, kf_ids=np.array(all_ids, dtype=np.int64), pt_ids=pts,
        )
        result = local_bundle_adjustment(problem, self.camera, self.config.optim, self.ba_factors)
        if not (np.all(np.isfinite(result.T_c_w)) and np.all(np.isfinite(result.X_w))):
            return
        for i, k in enumerate(all_ids):
            if not fixed[i]:
                map_.keyframes[k].T_c_w = rigid(result.T_c_w[i])
        map_.points.X_w[pts] = result.X_w
        out = np.flatnonzero(~np.asarray(result.inlier, dtype=bool))
        for k in np.unique(obs_kf[out]):
            m = out[obs_kf[out] == k]
            map_.erase_observations(map_.keyframes[int(k)], obs_kp[m])
        dead = pts[map_.points.n_obs[pts] <= 0]
        map_.cull_points(dead)
        # As ORB-SLAM2: normals and distances of all moved points; a descriptor only changes with the
        # observations, so only the points that lost some recompute theirs.
        map_.update_point_descriptors_and_normals(np.unique(obs_pt[out]), self.scale_factors)
        map_.update_point_descriptors_and_normals(pts, self.scale_factors, descriptors=False)

    # ------------------------------------------------------------ keyframe culling
    def cull_keyframes(self, kf: KeyFrame, map_: Map) -> None:
        """Drop covisible keyframes whose close points are >= 90% seen by >= 3 other keyframes at
        the same or a finer scale (ORB-SLAM2's KeyFrameCulling)."""
        first_id = min(map_.keyframes)
        for k in map_.covisible(kf.id):
            if k == first_id or k == kf.id or k not in map_.keyframes:
                continue
            other = map_.keyframes[k]
            idx = np.flatnonzero((other.point_ids >= 0) & (other.depth > 0) & (other.depth <= other.th_depth))
            if len(idx) == 0:
                continue
            pts = other.point_ids[idx]
            o_kf, o_pt, o_kp = map_.observers(pts)
            level_of_pt = np.full(map_.points.size, 0, dtype=np.int64)
            level_of_pt[pts] = other.keypoints.octave[idx]
            octs = np.empty(len(o_kf), dtype=np.int64)
            for kk in np.unique(o_kf):
                m = o_kf == kk
                octs[m] = map_.keyframes[int(kk)].keypoints.octave[o_kp[m]]
            good = (o_kf != k) & (octs <= level_of_pt[o_pt] + 1)
            n_obs_other = np.bincount(o_pt[good], minlength=map_.points.size)[pts]
            redundant = (n_obs_other >= self.cfg.kf_cull_observers) & (map_.points.n_obs[pts] > self.cfg.kf_cull_observers)
            if np.count_nonzero(redundant) > self.cfg.kf_cull_redundancy * len(idx):
                neighbours = map_.covisible(k)
                map_.erase_keyframe(other)
                for n in neighbours:
                    if n in map_.keyframes:
                        map_.update_connections(map_.keyframes[n], self.cfg.covisibility_min_weight)
