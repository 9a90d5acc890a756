"""Static map points stored as contiguous arrays (struct of arrays), indexed by a point id.

One row per point ever created; culled points keep their row with `alive = False` (ids stay valid,
so frames holding an id can check it), and fused points record the id that replaced them.
"""

from __future__ import annotations

import numpy as np

from dynaslam2.map.columns import ColumnStore

class MapPoints(ColumnStore):
    """Arrays of map-point attributes (ORB-SLAM2's MapPoint, vectorized).

    X_w: position; desc: representative ORB descriptor; normal: mean viewing direction;
    min_dist/max_dist: scale-invariance distance range; n_visible/n_found: tracking counters
    (found ratio = n_found / n_visible); n_obs: observation count (stereo observations count 2, as ORB-SLAM2); first_kf/ref_kf: keyframe ids;
    replaced_by: the id of the point this one was fused into (-1 if none).
    """

    COLUMNS = (
        ("X_w", (3,), np.float64, 0.0),
        ("desc", (32,), np.uint8, 0),
        ("normal", (3,), np.float64, 0.0),
        ("min_dist", (), np.float64, 0.0),
        ("max_dist", (), np.float64, np.inf),
        ("n_visible", (), np.int64, 0),
        ("n_found", (), np.int64, 0),
        ("n_obs", (), np.int64, 0),
        ("first_kf", (), np.int64, -1),
        ("ref_kf", (), np.int64, -1),
        ("alive", (), bool, False),
        ("replaced_by", (), np.int64, -1),
        ("last_frame_seen", (), np.int64, -1),
    )

    def __init__(self, capacity: int = 4096) -> None:
        super().__init__(capacity)

    def add(self, X_w: np.ndarray, desc: np.ndarray, kf_id: int) -> np.ndarray:
        """Append points created by keyframe `kf_id`; returns their ids."""
        ids = self._append(len(X_w))
        self.X_w[ids] = X_w
        self.desc[ids] = desc
        self.n_visible[ids] = 1
        self.n_found[ids] = 1
        self.first_kf[ids] = kf_id
        self.ref_kf[ids] = kf_id
        self.alive[ids] = True
        return ids

    def resolve(self, ids: np.ndarray) -> np.ndarray:
        """Follow fusion replacements; returns ids of living points or -1."""
        ids = np.asarray(ids, dtype=np.int64).copy()
        for _ in range(8):
            valid = ids >= 0
            nxt = np.full_like(ids, -1)
            nxt[valid] = self.replaced_by[ids[valid]]
            follow = nxt >= 0
            if not follow.any():
                break
            ids[follow] = nxt[follow]
        ok = ids >= 0
        ids[ok] = np.where(self.alive[ids[ok]], ids[ok], -1)
        return ids

    def found_ratio(self, ids: np.ndarray) -> np.ndarray:
        return self.n_found[ids] / np.maximum(self.n_visible[ids], 1)


def descriptor_distances(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Hamming distances between broadcastable (..., 32) uint8 descriptor arrays -> (...) int32
    (xor and popcount on 64-bit words)."""
    words_a = np.ascontiguousarray(A, dtype=np.uint8).view(np.uint64)
    words_b = np.ascontiguousarray(B, dtype=np.uint8).view(np.uint64)
    return np.bitwise_count(np.bitwise_xor(words_a, words_b)).sum(-1, dtype=np.int32)


def distinctive_descriptors(group: np.ndarray, desc: np.ndarray, n_groups: int) -> np.ndarray:
    """Per group, the descriptor with the least median distance to the others (ORB-SLAM2's
    ComputeDistinctiveDescriptors), batched over groups of equal size.

    group: (M,) group index of each descriptor in `desc` (M, 32); returns (n_groups, 32)
    (zeros for empty groups).
    """
    out = np.zeros((n_groups, 32), dtype=np.uint8)
    if len(group) == 0:
        return out
    order = np.argsort(group, kind="stable")
    g_sorted = group[order]
    starts = np.flatnonzero(np.r_[True, g_sorted[1:] != g_sorted[:-1]])
    counts = np.diff(np.r_[starts, len(g_sorted)])
    for n in np.unique(counts):
        sel = starts[counts == n]
        rows = order[sel[:, None] + np.arange(n)[None, :]]  # (G, n)
        D = desc[rows]  # (G, n, 32)
        if n <= 2:
            best = np.zeros(len(sel), dtype=np.int64)
        else:
            dist = descriptor_distances(D[:, :, None, :], D[:, None, :, :])  # (G, n, n)
            med = np.sort(dist, axis=2)[:, :, (n - 1) // 2]
            best = np.argmin(med, axis=1)
        out[g_sorted[sel]] = D[np.arange(len(sel)), best]
    return out
