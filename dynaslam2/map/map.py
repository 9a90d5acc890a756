"""The static map: keyframes, map points, the observation table and the covisibility graph.

Observations live in one contiguous table (keyframe id, point id, keypoint index, valid) so that
queries over many points (their observers, descriptors, normals) are vectorized; each keyframe keeps
`point_ids` / `obs_row` arrays pointing into it. Covisibility weights = number of shared points.
"""

from __future__ import annotations

import numpy as np

from dynaslam2.map.keyframe import KeyFrame
from dynaslam2.map.map_point import MapPoints, distinctive_descriptors


class ObservationTable:
    """Rows (kf, pt, kp, w, valid); erased rows stay with valid = False. `w` = 2 for a stereo
    observation and 1 for a monocular one (ORB-SLAM2's observation count)."""

    def __init__(self, capacity: int = 16384) -> None:
        self.size = 0
        self.kf = np.zeros(capacity, dtype=np.int64)
        self.pt = np.zeros(capacity, dtype=np.int64)
        self.kp = np.zeros(capacity, dtype=np.int64)
        self.w = np.zeros(capacity, dtype=np.int64)
        self.valid = np.zeros(capacity, dtype=bool)

    def append(self, kf: np.ndarray, pt: np.ndarray, kp: np.ndarray, w: np.ndarray) -> np.ndarray:
        n = len(pt)
        if self.size + n > len(self.kf):
            cap = max(2 * len(self.kf), self.size + n)
            for name in ("kf", "pt", "kp", "w", "valid"):
                old = getattr(self, name)
                new = np.zeros(cap, dtype=old.dtype)
                new[: self.size] = old[: self.size]
                setattr(self, name, new)
        rows = np.arange(self.size, self.size + n)
        self.kf[rows], self.pt[rows], self.kp[rows], self.w[rows], self.valid[rows] = kf, pt, kp, w, True
        self.size += n
        return rows

    def rows_of_points(self, pt_ids: np.ndarray, n_points: int) -> np.ndarray:
        """Valid rows observing any of `pt_ids`."""
        sel = np.zeros(n_points, dtype=bool)
        sel[pt_ids] = True
        s = self.size
        return np.flatnonzero(self.valid[:s] & sel[self.pt[:s]])


class Map:
    """One map segment: keyframes, points and their covisibility graph (ORB-SLAM2's Map)."""

    def __init__(self, segment: int = 0) -> None:
        self.segment = segment
        self.points = MapPoints()
        self.obs = ObservationTable()
        self.keyframes: dict[int, KeyFrame] = {}
        self.covisibility: dict[int, dict[int, int]] = {}

    # ----------------------------------------------------------------- keyframes
    def add_keyframe(self, kf: KeyFrame) -> None:
        self.keyframes[kf.id] = kf
        self.covisibility[kf.id] = {}

    def erase_keyframe(self, kf: KeyFrame) -> None:
        """Remove a keyframe (culling): its observations and its covisibility edges."""
        kp = kf.matched()
        self.erase_observations(kf, kp)
        kf.bad = True
        for other in self.covisibility.pop(kf.id, {}):
            self.covisibility.get(other, {}).pop(kf.id, None)
        del self.keyframes[kf.id]

    # --------------------------------------------------------------------- points
    def add_points(self, kf: KeyFrame, kp_idx: np.ndarray, X_w: np.ndarray) -> np.ndarray:
        """New points created by `kf` at keypoints `kp_idx` (observed there); returns ids."""
        ids = self.points.add(X_w, kf.keypoints.desc[kp_idx], kf.id)
        self.add_observations(kf, kp_idx, ids)
        return ids

    def add_observations(self, kf: KeyFrame, kp_idx: np.ndarray, pt_ids: np.ndarray) -> None:
        """`kf` observes points `pt_ids` at keypoints `kp_idx` (keypoints must be free)."""
        kp_idx = np.asarray(kp_idx, dtype=np.int64)
        pt_ids = np.asarray(pt_ids, dtype=np.int64)
        if len(kp_idx) == 0:
            return
        w = np.where(kf.u_right[kp_idx] >= 0, 2, 1)
        rows = self.obs.append(np.full(len(kp_idx), kf.id), pt_ids, kp_idx, w)
        kf.point_ids[kp_idx] = pt_ids
        kf.obs_row[kp_idx] = rows
        np.add.at(self.points.n_obs, pt_ids, w)

    def erase_observations(self, kf: KeyFrame, kp_idx: np.ndarray) -> None:
        kp_idx = np.asarray(kp_idx, dtype=np.int64)
        kp_idx = kp_idx[kf.point_ids[kp_idx] >= 0]
        if len(kp_idx) == 0:
            return
        rows = kf.obs_row[kp_idx]
        self.obs.valid[rows] = False
        np.subtract.at(self.points.n_obs, kf.point_ids[kp_idx], self.obs.w[rows])
        kf.point_ids[kp_idx] = -1
        kf.obs_row[kp_idx] = -1

    def cull_points(self, pt_ids: np.ndarray) -> None:
        """Mark points bad and drop all their observations (ORB-SLAM2's MapPoint::SetBadFlag)."""
        pt_ids = np.unique(np.asarray(pt_ids, dtype=np.int64))
        if len(pt_ids) == 0:
            return
        rows = self.obs.rows_of_points(pt_ids, self.points.size)
        self._drop_rows(rows)
        self.points.alive[pt_ids] = False
        self.points.n_obs[pt_ids] = 0

    def _drop_rows(self, rows: np.ndarray) -> None:
        for kf_id in np.unique(self.obs.kf[rows]):
            kf = self.keyframes.get(int(kf_id))
            r = rows[self.obs.kf[rows] == kf_id]
            if kf is not None:
                kf.point_ids[self.obs.kp[r]] = -1
                kf.obs_row[self.obs.kp[r]] = -1
        np.subtract.at(self.points.n_obs, self.obs.pt[rows], self.obs.w[rows])
        self.obs.valid[rows] = False

    def replace_points(self, old_ids: np.ndarray, new_ids: np.ndarray) -> None:
        """Fuse each `old` point into its `new` point (ORB-SLAM2's MapPoint::Replace): observations
        move over unless that keyframe already sees the new point; counters add up."""
        old_ids = np.asarray(old_ids, dtype=np.int64)
        new_ids = np.asarray(new_ids, dtype=np.int64)
        keep = (old_ids != new_ids) & self.points.alive[old_ids] & self.points.alive[new_ids]
        old_ids, new_ids = old_ids[keep], new_ids[keep]
        if len(old_ids) == 0:
            return
        # One replacement per old point; a point used as a target is not also replaced.
        _, first = np.unique(old_ids, return_index=True)
        old_ids, new_ids = old_ids[first], new_ids[first]
        ok = ~np.isin(new_ids, old_ids)
        old_ids, new_ids = old_ids[ok], new_ids[ok]
        target = np.full(self.points.size, -1, dtype=np.int64)
        target[old_ids] = new_ids
        rows = self.obs.rows_of_points(old_ids, self.points.size)
        tgt = target[self.obs.pt[rows]]
        # Does the observing keyframe already see the target point?
        stride = self.points.size + 1
        tgt_rows = self.obs.rows_of_points(new_ids, self.points.size)
        existing = self.obs.kf[tgt_rows] * stride + self.obs.pt[tgt_rows]
        pair_kf = self.obs.kf[rows]
        dup = np.isin(pair_kf * stride + tgt, existing)
        # A keyframe may also see two old points mapped to the same target: keep the first.
        key = pair_kf * stride + tgt
        _, first_of_key = np.unique(key, return_index=True)
        dup_within = np.ones(len(rows), dtype=bool)
        dup_within[first_of_key] = False
        drop = dup | dup_within
        self._drop_rows(rows[drop])
        move = rows[~drop]
        np.subtract.at(self.points.n_obs, self.obs.pt[move], self.obs.w[move])
        self.obs.pt[move] = tgt[~drop]
        np.add.at(self.points.n_obs, tgt[~drop], self.obs.w[move])
        for kf_id in np.unique(self.obs.kf[move]):
            kf = self.keyframes.get(int(kf_id))
            r = move[self.obs.kf[move] == kf_id]
            if kf is not None:
                kf.point_ids[self.obs.kp[r]] = self.obs.pt[r]
        np.add.at(self.points.n_visible, new_ids, self.points.n_visible[old_ids])
        np.add.at(self.points.n_found, new_ids, self.points.n_found[old_ids])
        self.points.alive[old_ids] = False
        self.points.n_obs[old_ids] = 0
        self.points.replaced_by[old_ids] = new_ids

    def update_point_descriptors_and_normals(self, pt_ids: np.ndarray, scale_factors: np.ndarray,
                                             descriptors: bool = True) -> None:
        """Representative descriptor, mean viewing direction and scale-invariance distances of
        points (ORB-SLAM2's ComputeDistinctiveDescriptors + UpdateNormalAndDepth), vectorized;
        `descriptors=False`: UpdateNormalAndDepth only (the descriptors depend on the observations alone)."""
        pt_ids = np.unique(np.asarray(pt_ids, dtype=np.int64))
        pt_ids = pt_ids[self.points.alive[pt_ids]]
        if len(pt_ids) == 0:
            return
        rows = self.obs.rows_of_points(pt_ids, self.points.size)
        if len(rows) == 0:
            return
        local = np.full(self.points.size, -1, dtype=np.int64)
        local[pt_ids] = np.arange(len(pt_ids))
        grp = local[self.obs.pt[rows]]
        kf_of_row = self.obs.kf[rows]
        kp_of_row = self.obs.kp[rows]
        desc = np.empty((len(rows) if descriptors else 0, 32), dtype=np.uint8)
        centers = np.empty((len(rows), 3))
        octave = np.empty(len(rows), dtype=np.int64)
        by_kf = np.argsort(kf_of_row, kind="stable")  # the rows of each keyframe: one slice of by_kf
        bounds = np.flatnonzero(np.r_[True, kf_of_row[by_kf][1:] != kf_of_row[by_kf][:-1], True])
        for start, end in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
            r = by_kf[start:end]
            kf = self.keyframes[int(kf_of_row[r[0]])]
            if descriptors:
                desc[r] = kf.keypoints.desc[kp_of_row[r]]
            octave[r] = kf.keypoints.octave[kp_of_row[r]]
            centers[r] = kf.center_w
        has_obs = np.bincount(grp, minlength=len(pt_ids)) > 0
        if descriptors:
            rep = distinctive_descriptors(grp, desc, len(pt_ids))
            self.points.desc[pt_ids[has_obs]] = rep[has_obs]
        X = self.points.X_w[pt_ids]
        rays = X[grp] - centers
        rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
        normal = np.column_stack([np.bincount(grp, rays[:, i], len(pt_ids)) for i in range(3)])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        self.points.normal[pt_ids[has_obs]] = normal[has_obs]
        # Reference keyframe: the one that created the point if it still observes it, else any observer.
        ref = self.points.ref_kf[pt_ids]
        is_ref_row = kf_of_row == ref[grp]
        ref_row = np.full(len(pt_ids), -1, dtype=np.int64)
        ref_row[grp[::-1]] = np.arange(len(rows))[::-1]  # first observer as a fallback
        ref_row[grp[is_ref_row]] = np.flatnonzero(is_ref_row)
        ok = has_obs & (ref_row >= 0)
        r = ref_row[ok]
        self.points.ref_kf[pt_ids[ok]] = kf_of_row[r]
        dist = np.linalg.norm(X[ok] - centers[r], axis=1)
        level_factor = scale_factors[octave[r]]
        self.points.max_dist[pt_ids[ok]] = dist * level_factor
        self.points.min_dist[pt_ids[ok]] = dist * level_factor / scale_factors[-1]

    # ------------------------------------------------------------- covisibility
    def update_connections(self, kf: KeyFrame, min_weight: int) -> None:
        """Recompute `kf`'s covisibility edges (ORB-SLAM2's KeyFrame::UpdateConnections)."""
        pts = kf.point_ids[kf.point_ids >= 0]
        rows = self.obs.rows_of_points(pts, self.points.size) if len(pts) else np.zeros(0, dtype=np.int64)
        others = self.obs.kf[rows]
        others = others[others != kf.id]
        ids, counts = np.unique(others, return_counts=True)
        old = self.covisibility.get(kf.id, {})
        for o in old:
            self.covisibility.get(o, {}).pop(kf.id, None)
        edges: dict[int, int] = {}
        if len(ids):
            keep = counts >= min_weight
            if not keep.any():
                keep = counts == counts.max()
            edges = {int(i): int(c) for i, c in zip(ids[keep], counts[keep]) if int(i) in self.keyframes}
        self.covisibility[kf.id] = edges
        for o, w in edges.items():
            self.covisibility[o][kf.id] = w

    def covisible(self, kf_id: int, n: int | None = None, min_weight: int = 0) -> list[int]:
        """Covisible keyframe ids, strongest first (ties by id, for determinism)."""
        edges = self.covisibility.get(kf_id, {})
        order = sorted((w, -o) for o, w in edges.items() if w >= min_weight)
        ids = [-o for w, o in reversed(order)]
        return ids if n is None else ids[:n]

    def points_of_keyframes(self, kf_ids: list[int]) -> np.ndarray:
        """Unique living point ids seen by the given keyframes."""
        if not kf_ids:
            return np.zeros(0, dtype=np.int64)
        seen = np.zeros(self.points.size, dtype=bool)  # a mark per point id: no sort of the concatenation
        for k in kf_ids:
            ids = self.keyframes[k].point_ids
            seen[ids[ids >= 0]] = True
        return np.flatnonzero(seen & self.points.alive[: self.points.size])

    def observers(self, pt_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(kf, pt, kp) of all valid observations of the points."""
        rows = self.obs.rows_of_points(np.asarray(pt_ids, dtype=np.int64), self.points.size)
        return self.obs.kf[rows], self.obs.pt[rows], self.obs.kp[rows]

    def __len__(self) -> int:
        return len(self.keyframes)
