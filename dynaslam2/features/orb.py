"""ORB features on an image pyramid, spread over the image (ORB-SLAM2's ORBextractor, ref. [1]).

Per level: FAST (non-maximum suppression) at `ini_th_fast`; each cell of ORB-SLAM2's grid
(~`cell_size` px) without a corner gets those of FAST at `min_th_fast` (ORB-SLAM2's two passes per
cell, done as two whole-level passes, the second on a copy blanked outside the empty cells; see
`_detect`). Each level is processed to the end before the next (its image stays in cache). The survivors are
spread with an adaptive uniform grid instead of ORB-SLAM2's octree: the largest square cell for which
at least the level's budget of cells is occupied, the best response per cell, then the budget's best
of those. Orientation is the intensity centroid (IC_Angle) on the level image; the rBRIEF descriptor is
OpenCV's ORB on the Gaussian-blurred level (same pattern and blur as ORB-SLAM2), computed on FAST's own
keypoint objects. OpenCV 5.0 keeps the angle of provided keypoints (checked in the tests).
"""

from __future__ import annotations

import contextlib
import os
import pickle
import select
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from itertools import repeat
from operator import attrgetter
from pathlib import Path

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from dynaslam2.config import ORBConfig
from dynaslam2.errors import InputError

HALF_PATCH = 15  # IC_Angle radius (ORB-SLAM2's HALF_PATCH_SIZE)


@dataclass
class Keypoints:
    """Keypoints of one image; `uv` in level-0 pixels (exact map from the level, `level_to_base`),
    `desc` 256-bit rBRIEF."""

    uv: np.ndarray  # (N,2) float32
    octave: np.ndarray  # (N,) int32
    angle: np.ndarray  # (N,) float32 degrees in [0, 360)
    response: np.ndarray  # (N,) float32 FAST score
    desc: np.ndarray  # (N,32) uint8

    def __len__(self) -> int:
        return len(self.uv)

    def subset(self, idx) -> "Keypoints":
        """Keypoints selected by an index array or a boolean mask."""
        return Keypoints(self.uv[idx], self.octave[idx], self.angle[idx], self.response[idx], self.desc[idx])

    @classmethod
    def empty(cls) -> "Keypoints":
        return cls(
            np.zeros((0, 2), np.float32),
            np.zeros(0, np.int32),
            np.zeros(0, np.float32),
            np.zeros(0, np.float32),
            np.zeros((0, 32), np.uint8),
        )

    @classmethod
    def concatenate(cls, parts: list["Keypoints"]) -> "Keypoints":
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("uv", "octave", "angle", "response", "desc")))


def to_gray(image: np.ndarray) -> np.ndarray:
    """uint8 HxW grey, or HxWx3 RGB converted to grey; anything else is an InputError."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise InputError(f"image: expected uint8 pixels, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if image.ndim != 2:
        raise InputError(f"image: expected HxW grey or HxWx3 RGB, got shape {image.shape}")
    return np.ascontiguousarray(image)


def level_budgets(n_features: int, n_levels: int, scale_factor: float) -> np.ndarray:
    """Features per level: ORB-SLAM2's geometric series with ratio 1/scale_factor, summing to n_features."""
    factor = 1.0 / scale_factor
    first = n_features * (1 - factor) / (1 - factor**n_levels)
    budgets = np.rint(first * factor ** np.arange(n_levels)).astype(np.int64)
    budgets[-1] = max(n_features - int(budgets[:-1].sum()), 0)
    return budgets


def level_scales(pyramid: list[np.ndarray]) -> np.ndarray:
    """(n_levels, 2) exact per-axis scales (W / W_l, H / H_l) of each level from the actual (rounded)
    level image sizes; differs from the nominal scale_factor**l by up to ~0.2% at 640x480."""
    h, w = pyramid[0].shape[:2]
    return np.array([(w / p.shape[1], h / p.shape[0]) for p in pyramid], np.float64)


def _open_cells(mask_sum: np.ndarray, scale_xy: np.ndarray, edge: int, w: int, h: int, cw: int, ch: int,
                n_cx: int, n_cy: int) -> np.ndarray:
    """(n_cy, n_cx) bool: the cells of a level's FAST grid (cw x ch from `edge`, corners < size - edge) that hold
    a pixel whose nearest level-0 pixel (`level_to_base`, clipped to the image) the mask allows; `mask_sum`:
    the integral image of the level-0 mask."""
    H, W = mask_sum.shape[0] - 1, mask_sum.shape[1] - 1

    def level0_range(first: np.ndarray, last: np.ndarray, scale: float, size: int) -> tuple[np.ndarray, np.ndarray]:
        """[lo, hi) of the level-0 pixels nearest to the level pixels first..last (monotonic in them)."""
        lo, hi = (np.clip(np.rint(level_to_base(p.astype(np.float64), scale)), 0, size - 1).astype(np.int64)
                  for p in (first, last))
        return lo, hi + 1

    x = edge + np.arange(n_cx) * cw
    y = edge + np.arange(n_cy) * ch
    u0, u1 = level0_range(x, np.minimum(x + cw, w - edge) - 1, scale_xy[0], W)
    v0, v1 = level0_range(y, np.minimum(y + ch, h - edge) - 1, scale_xy[1], H)
    S = mask_sum
    return S[v1[:, None], u1] - S[v0[:, None], u1] - S[v1[:, None], u0] + S[v0[:, None], u0] > 0


def level_to_base(xy: np.ndarray, scale_xy: np.ndarray) -> np.ndarray:
    """Level pixel coordinates -> level-0 pixels; pixel centres at integers, as cv2.resize maps them:
    u0 = (x_l + 0.5) * W / W_l - 0.5 per axis. `scale_xy` broadcasts against `xy` (e.g. (N,2) or (N,))."""
    return (xy + 0.5) * scale_xy - 0.5


def base_to_level(uv: np.ndarray, scale_xy: np.ndarray) -> np.ndarray:
    """Inverse of `level_to_base`: level-0 pixels -> level pixel coordinates."""
    return (uv + 0.5) / scale_xy - 0.5


def _ic_kernels() -> tuple[np.ndarray, np.ndarray]:
    """Weights u*[inside] and v*[inside] over the circular patch of radius HALF_PATCH (ORB-SLAM2's umax)."""
    vmax = int(np.floor(HALF_PATCH * np.sqrt(2.0) / 2 + 1))
    vmin = int(np.ceil(HALF_PATCH * np.sqrt(2.0) / 2))
    umax = np.zeros(HALF_PATCH + 1, np.int64)
    for v in range(vmax + 1):
        umax[v] = int(np.rint(np.sqrt(HALF_PATCH**2 - v * v)))
    v0 = 0
    for v in range(HALF_PATCH, vmin - 1, -1):  # make the circle symmetric, as ORB-SLAM2 does
        while umax[v0] == umax[v0 + 1]:
            v0 += 1
        umax[v] = v0
        v0 += 1
    r = np.arange(-HALF_PATCH, HALF_PATCH + 1)
    inside = np.abs(r)[None, :] <= umax[np.abs(r)][:, None]
    w_u = (r[None, :] * inside).astype(np.float32)
    w_v = (r[:, None] * inside).astype(np.float32)
    return w_u.ravel(), w_v.ravel()


def spread_best(xy: np.ndarray, response: np.ndarray, n_keep: int, area: float, tol: float = 1.05) -> np.ndarray:
    """Indices of <= n_keep points spread over the image: the best response in each cell of the largest
    square grid (within a factor `tol`) with >= n_keep occupied cells, then the n_keep best of those.
    Ties go to the lower index (deterministic). `xy` must be >= 0; `area` is the image area in px^2."""
    n = len(xy)
    if n <= n_keep:
        return np.arange(n)
    score = response.astype(np.uint8)  # FAST scores are integers < 256: a radix sort
    order = np.argsort(255 - score if np.array_equal(score, response) else -response, kind="stable")  # best first
    x = xy[order, 0].astype(np.float64)  # float32 -> float64 is exact: cell indices floor(x / cell)
    y = xy[order, 1].astype(np.float64)
    x_max, y_max = float(x.max()), float(y.max())

    def cell_keys(cell: float) -> tuple[np.ndarray, int]:
        """Cell index of each point (row-major) and the number of cells of the grid."""
        stride = int(x_max / cell) + 1
        keys = (y / cell).astype(np.int64)
        keys *= stride
        keys += (x / cell).astype(np.int64)
        return keys, (int(y_max / cell) + 1) * stride

    # A grid of 2*sqrt(area/n_keep) cells has < n_keep cells: an upper bound; 1 px cells: n occupied.
    lo, hi = 1.0, 2.0 * np.sqrt(area / n_keep)
    while hi / lo > tol:
        mid = np.sqrt(lo * hi)
        keys, n_cells = cell_keys(mid)
        occupied = np.zeros(n_cells, bool)
        occupied[keys] = True
        if np.count_nonzero(occupied) >= n_keep:
            lo = mid
        else:
            hi = mid
    keys, n_cells = cell_keys(lo)
    if n_cells <= 1 << 16:
        keys = keys.astype(np.uint16)  # a radix sort
    by_key = np.argsort(keys, kind="stable")  # within a cell: best response first
    k_sorted = keys[by_key]
    winners = by_key[np.r_[True, k_sorted[1:] != k_sorted[:-1]]]
    winners.sort()  # positions in the response order
    return order[winners[:n_keep]]


class ORBExtractor:
    """ORB-SLAM2's ORBextractor: pyramid, distributed FAST, orientation and rBRIEF (see module doc)."""

    def __init__(self, cfg: ORBConfig):
        self.cfg = cfg
        self.n_levels = cfg.n_levels
        self.scale_factors = (cfg.scale_factor ** np.arange(cfg.n_levels)).astype(np.float64)
        self.inv_scale_factors = 1.0 / self.scale_factors
        self.level_sigma2 = self.scale_factors**2
        self.inv_level_sigma2 = 1.0 / self.level_sigma2
        self.level_budgets = level_budgets(cfg.n_features, cfg.n_levels, cfg.scale_factor)
        self._w_u, self._w_v = _ic_kernels()
        self._fast_ini = cv2.FastFeatureDetector_create(cfg.ini_th_fast, True)
        self._fast_min = cv2.FastFeatureDetector_create(cfg.min_th_fast, True)
        self._worker: tuple[int, _Worker | ThreadPoolExecutor] | None = None  # (owner pid, worker) for extract_pair
        self._orb = cv2.ORB_create(
            nfeatures=1, nlevels=1, edgeThreshold=cfg.edge_threshold, patchSize=cfg.patch_size, fastThreshold=cfg.min_th_fast
        )

    def build_pyramid(self, gray: np.ndarray) -> list[np.ndarray]:
        """Level l = level l-1 resized by 1/scale_factor (bilinear), as ORB-SLAM2. RGB input is converted."""
        gray = to_gray(gray)
        pyramid = [gray]
        h, w = gray.shape
        for level in range(1, self.n_levels):
            size = (int(np.rint(w * self.inv_scale_factors[level])), int(np.rint(h * self.inv_scale_factors[level])))
            if min(size) < 2 * self.cfg.edge_threshold + 1:
                pyramid.append(np.zeros((max(size[1], 1), max(size[0], 1)), np.uint8))  # too small: no features
                continue
            pyramid.append(cv2.resize(pyramid[-1], size, interpolation=cv2.INTER_LINEAR))
        return pyramid

    def extract(
        self, pyramid: list[np.ndarray], mask: np.ndarray | None = None, n_features: int | None = None,
        timing_ms: dict[str, float] | None = None, max_level: int | None = None
    ) -> Keypoints:
        """Distributed ORB keypoints of all levels. `mask` (HxW bool/uint8 at level 0, True/non-zero = usable)
        removes candidates before the distribution, so the budget goes to the usable area. `n_features`
        overrides the configured budget (e.g. more features on the right image of a stereo pair);
        `max_level` keeps only the budgets of levels 0..max_level (the others' are dropped, not moved).
        `timing_ms`, when given, receives the wall ms of the stages: fast, spread, orientation, descriptors."""
        if len(pyramid) != self.n_levels:
            raise InputError(f"pyramid: expected {self.n_levels} levels, got {len(pyramid)}")
        if mask is not None:
            mask = np.asarray(mask)
            if mask.shape != pyramid[0].shape:
                raise InputError(f"mask: expected shape {pyramid[0].shape}, got {mask.shape}")
            mask = mask.astype(bool, copy=False)
        # FAST only around the cells the mask leaves open (`_detect`) where it closes most of the image: the
        # cell test costs ~0.1 ms per level, more than it saves under a mask that closes a few objects.
        sparse = mask is not None and np.count_nonzero(mask) <= 0.5 * mask.size
        mask_sum = cv2.integral(mask.view(np.uint8)) if sparse else None
        budgets = self.level_budgets
        if n_features is not None:
            if n_features <= 0:
                raise InputError(f"n_features: expected a positive integer, got {n_features}")
            budgets = level_budgets(int(n_features), self.n_levels, self.cfg.scale_factor)
        if max_level is not None:
            budgets = np.where(np.arange(self.n_levels) <= max_level, budgets, 0)
        scales = level_scales(pyramid)
        parts = []
        stages = dict.fromkeys(("fast", "spread", "orientation", "descriptors"), 0.0)
        for lv in np.flatnonzero(budgets > 0).tolist():  # one level at a time: its image stays in cache
            part = self._extract_level(pyramid[lv], scales[lv], mask, mask_sum, int(budgets[lv]), stages)
            if part is not None:
                parts.append((lv, part))
        if timing_ms is not None:
            timing_ms.update({k: 1e3 * v for k, v in stages.items()})
        if not parts:
            return Keypoints.empty()
        return Keypoints.concatenate([Keypoints(level_to_base(xy.astype(np.float64), scales[lv]).astype(np.float32),
                                                np.full(len(xy), lv, np.int32), angle, resp, desc)
                                      for lv, (xy, angle, resp, desc) in parts])

    def extract_pair(
        self, pyr_left: list[np.ndarray], pyr_right: list[np.ndarray], mask_left: np.ndarray | None = None, n_features_right: int | None = None
    ) -> tuple[Keypoints, Keypoints]:
        """`extract` on both images of a stereo pair (same result). With cfg.threads > 1 the right image runs
        in a worker (cfg.worker) while this one does the left: a process (started at the first call, fed by a
        pipe) runs in parallel; a thread shares the GIL (only OpenCV's calls and large numpy operations overlap)."""
        if self.cfg.threads <= 1 or not self.start_worker():  # a process still starting: no wait
            return self.extract(pyr_left, mask_left), self.extract(pyr_right, None, n_features_right)
        right = self._worker[1].submit(_extract, self.cfg, pyr_right, n_features_right)
        try:
            left = self.extract(pyr_left, mask_left)
        except BaseException:
            with contextlib.suppress(Exception):  # read the right reply: the worker stays in step
                right.result()
            raise
        return left, right.result()

    def start_worker(self, wait: bool = False) -> bool:
        """Start the worker of `extract_pair` now (else its first call does; a process takes ~0.3 s, during
        which pairs run here). With `wait`, until it has started. Returns whether it has."""
        if self._worker is None or self._worker[0] != os.getpid():  # a forked child gets its own worker
            self._worker = (os.getpid(), _Worker() if self.cfg.worker == "process" else ThreadPoolExecutor(1, "orb-right"))
        worker = self._worker[1]
        return not isinstance(worker, _Worker) or worker.ready(None if wait else 0.0)

    def __del__(self) -> None:
        worker = getattr(self, "_worker", None)
        if worker is not None and worker[0] == os.getpid():
            worker[1].shutdown(wait=False)

    def _detect(self, img: np.ndarray, scale_xy: np.ndarray, mask: np.ndarray | None,
                mask_sum: np.ndarray | None) -> tuple[tuple, np.ndarray, np.ndarray, np.ndarray]:
        """FAST candidates by ORB-SLAM2's per-cell rule: a cell keeps its corners at ini_th_fast, or those at
        min_th_fast where it has none. Same corners and scores as FAST on the whole level: FAST at ini_th_fast
        runs on the level less its edge, FAST at min_th_fast on a copy blanked outside the cells without a
        corner, except the 4 px rim that the scores (3 px radius) and the non-maximum suppression (1 px more)
        of their corners read. Corners count only >= edge_threshold inside the level and where `mask`
        (level 0) allows, in FAST's raster order (strong, then fallback); `mask_sum`: its integral image, or
        None to search every cell (the same corners).
        Returns (the cv2 keypoints of the FAST calls, index of each candidate in them, integer xy at this
        level, score); the keypoint objects are reused for the descriptors (`_describe`)."""
        cfg = self.cfg
        edge = cfg.edge_threshold
        h, w = img.shape
        border = edge - 3  # ORB-SLAM2's minBorderX: cells cover [border, size - border), corners >= 3 px inside
        if w - 2 * border < 7 or h - 2 * border < 7:
            return (), np.zeros(0, np.int64), np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
        n_cx = max(1, (w - 2 * border) // cfg.cell_size)
        n_cy = max(1, (h - 2 * border) // cfg.cell_size)
        cw = int(np.ceil((w - 2 * border) / n_cx))
        ch = int(np.ceil((h - 2 * border) / n_cy))

        def usable(idx: np.ndarray, xy: np.ndarray) -> np.ndarray:
            """The corners `idx` of `xy` where `mask` allows (the level-0 pixel nearest to each, `level_to_base`)."""
            if mask is None:
                return idx
            uv = np.rint(level_to_base(xy[idx].astype(np.float64), scale_xy)).astype(np.int64)
            return idx[mask[np.clip(uv[:, 1], 0, mask.shape[0] - 1), np.clip(uv[:, 0], 0, mask.shape[1] - 1)]]

        # Where `mask` allows nothing no corner counts: FAST runs only on the bounding box of the cells that allow
        # some (the whole grid without a mask), viewed with a 4 px rim so that the corners inside it keep their
        # true scores and suppression neighbours.
        if mask_sum is None:
            open_cells = np.ones((n_cy, n_cx), bool)
        else:
            open_cells = _open_cells(mask_sum, scale_xy, edge, w, h, cw, ch, n_cx, n_cy)
        rows, cols = np.flatnonzero(open_cells.any(axis=1)), np.flatnonzero(open_cells.any(axis=0))
        if len(rows) == 0:
            return (), np.zeros(0, np.int64), np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
        x0, x1 = edge + cols[0] * cw, min(edge + (cols[-1] + 1) * cw, w - edge)
        y0, y1 = edge + rows[0] * ch, min(edge + (rows[-1] + 1) * ch, h - edge)
        view = img[y0 - 4 : y1 + 4, x0 - 4 : x1 + 4]
        offset = np.array([x0 - 4, y0 - 4], np.float32)
        raw = self._fast_ini.detect(view)
        xy = np.asarray(cv2.KeyPoint.convert(raw), np.float32).reshape(-1, 2) + offset
        src = usable(np.flatnonzero((xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)), xy)
        xy, resp = xy[src], np.fromiter(map(attrgetter("response"), raw), np.float32, len(raw))[src]
        strong = np.zeros((n_cy, n_cx), bool)
        cell = (xy.astype(np.int64) - edge) // (cw, ch)  # corners are inside the grid
        strong[cell[:, 1], cell[:, 0]] = True
        weak = open_cells & ~strong
        if not weak.any():
            return raw, src, xy, resp
        # Second pass on a copy blanked outside the empty cells except a 4 px rim (all that the scores and
        # the suppression of their corners read); FAST's mask keeps the corners inside the empty cells.
        grid = np.repeat(np.repeat(weak, ch, axis=0), cw, axis=1)[y0 - edge : y1 - edge, x0 - edge : x1 - edge]
        weak_cells = np.zeros(view.shape, np.uint8)  # the view's rim lies outside the open cells: never weak
        weak_cells[4:-4, 4:-4] = grid.view(np.uint8) * np.uint8(255)
        rim = cv2.dilate(weak_cells, np.ones((9, 9), np.uint8))
        raw_w = self._fast_min.detect(cv2.bitwise_and(view, rim), weak_cells)
        if not raw_w:
            return raw, src, xy, resp
        xy_w = np.asarray(cv2.KeyPoint.convert(raw_w), np.float32).reshape(-1, 2) + offset
        src_w = usable(np.arange(len(raw_w)), xy_w)
        resp_w = np.fromiter(map(attrgetter("response"), raw_w), np.float32, len(raw_w))
        return raw + raw_w, np.concatenate([src, src_w + len(raw)]), np.concatenate([xy, xy_w[src_w]]), np.concatenate([resp, resp_w[src_w]])

    def _extract_level(self, img: np.ndarray, scale_xy: np.ndarray, mask: np.ndarray | None,
                       mask_sum: np.ndarray | None, budget: int, stages: dict[str, float]):
        """(xy at this level, angle, response, descriptors) of one level's spread keypoints, or None; adds the
        seconds of each stage to `stages`."""
        t0 = time.perf_counter()
        raw, src, xy, resp = self._detect(img, scale_xy, mask, mask_sum)
        t1 = time.perf_counter()
        stages["fast"] += t1 - t0
        if len(xy) == 0:
            return None
        keep = spread_best(xy, resp, budget, float(img.shape[0] * img.shape[1]))
        keep.sort()
        kps = list(map(raw.__getitem__, src[keep].tolist()))
        xy, resp = xy[keep], resp[keep]
        t2 = time.perf_counter()
        angle = self._angles(img, xy)
        t3 = time.perf_counter()
        desc = self._describe(img, kps, xy, angle)
        stages["spread"] += t2 - t1
        stages["orientation"] += t3 - t2
        stages["descriptors"] += time.perf_counter() - t3
        return xy, angle, resp, desc

    def _angles(self, img: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Intensity-centroid orientation in degrees [0, 360) (ORB-SLAM2's IC_Angle) of integer `xy`."""
        windows = sliding_window_view(img, (2 * HALF_PATCH + 1, 2 * HALF_PATCH + 1))
        ix = xy[:, 0].astype(np.int64) - HALF_PATCH
        iy = xy[:, 1].astype(np.int64) - HALF_PATCH
        patches = windows[iy, ix].reshape(len(xy), -1).astype(np.float32)
        # Integer moments below 2**24: exact in float32 in any summation order. einsum, not BLAS:
        # a multithreaded gemv stalls on a loaded machine (measured 30x slower at 1000 keypoints).
        m_10 = np.einsum("ij,j->i", patches, self._w_u)
        m_01 = np.einsum("ij,j->i", patches, self._w_v)
        return (np.degrees(np.arctan2(m_01, m_10)) % 360.0).astype(np.float32)

    def describe(self, pyramid: list[np.ndarray], kp: Keypoints, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(angle, descriptors) of the keypoints `idx` of `kp` computed again on `pyramid` (same geometry,
        other pixels: e.g. levels whose background is blanked), as `extract` computes them."""
        angle = np.empty(len(idx), np.float32)
        desc = np.empty((len(idx), 32), np.uint8)
        scales = level_scales(pyramid)
        octave = kp.octave[idx]
        for lv in np.unique(octave).tolist():
            sel = np.flatnonzero(octave == lv)
            xy = np.rint(base_to_level(kp.uv[idx[sel]].astype(np.float64), scales[lv])).astype(np.float32)
            angle[sel] = self._angles(pyramid[lv], xy)
            desc[sel] = self._describe(pyramid[lv], [cv2.KeyPoint() for _ in sel], xy, angle[sel])
        return angle, desc

    def _describe(self, img: np.ndarray, kps: list, xy: np.ndarray, angle: np.ndarray) -> np.ndarray:
        """rBRIEF descriptors on the blurred level (OpenCV's ORB) of the keypoint objects `kps` (FAST's own in
        `extract`: none built in Python there), moved to level coordinates `xy` and given `angle`. All keypoints are
        >= edge_threshold inside the level: OpenCV keeps them, in order."""
        list(map(setattr, kps, repeat("pt"), zip(xy[:, 0].tolist(), xy[:, 1].tolist())))
        list(map(setattr, kps, repeat("angle"), angle.tolist()))
        kps_out, desc = self._orb.compute(img, kps)
        if len(kps_out) != len(kps):
            raise RuntimeError(f"ORB dropped {len(kps) - len(kps_out)} of {len(kps)} keypoints inside the edge")
        return desc



def _extract(cfg: ORBConfig, pyramid: list[np.ndarray], n_features: int | None) -> Keypoints:
    """`ORBExtractor.extract` without a mask, for the worker of `extract_pair` (a fresh extractor: its OpenCV
    detectors are not shared between threads)."""
    return ORBExtractor(cfg).extract(pyramid, None, n_features)


class _Worker:
    """A Python process that runs `submit(fn, *args)` calls one at a time: requests and results are pickled
    through its stdin and its own stdout (`_serve`). Started with `-c`, so it never imports the caller's main
    script (multiprocessing's spawn would, and fails on a script read from stdin)."""

    def __init__(self) -> None:
        package_root = str(Path(__file__).resolve().parents[2])
        bootstrap = f"import sys; sys.path.insert(0, {package_root!r}); from dynaslam2.features.orb import _serve; _serve()"
        self._proc = subprocess.Popen([sys.executable, "-c", bootstrap], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self._lock = threading.Lock()  # one request in flight
        self._ready = False  # the worker has imported its modules (its first reply)
        for pipe in (self._proc.stdin, self._proc.stdout):  # a pyramid in one go: no handoff per 64 KiB
            try:
                import fcntl  # Linux: F_SETPIPE_SZ

                fcntl.fcntl(pipe.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), 1 << 20)
            except (ImportError, OSError):  # elsewhere, or above /proc/sys/fs/pipe-max-size: smaller steps
                pass

    def ready(self, timeout: float | None = 0.0) -> bool:
        """Whether the worker has started (it replies once, after its imports), waiting up to `timeout` s
        (None: until it has)."""
        if not self._ready and select.select([self._proc.stdout], [], [], timeout)[0]:
            self._ready = self._read() is None
        return self._ready

    def submit(self, fn, *args) -> "_Worker":
        """Send the call now; `result()` waits for its reply (as a Future's)."""
        self._lock.acquire()
        try:
            pickle.dump((fn, args), self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.flush()
        except BaseException:
            self._lock.release()
            raise
        return self

    def result(self):
        """The reply to the call in flight; re-raises the worker's exception."""
        try:
            return self._read()
        finally:
            self._lock.release()

    def _read(self):
        try:
            ok, value = pickle.load(self._proc.stdout)
        except EOFError:
            raise RuntimeError(f"ORB worker process exited (code {self._proc.poll()})") from None
        if not ok:
            raise value
        return value

    def shutdown(self, wait: bool = True) -> None:
        """Close the request pipe: the worker exits."""
        self._proc.stdin.close()
        if wait:
            self._proc.wait()


def _serve() -> None:
    """The loop of a `_Worker` process: unpickle (fn, args) from stdin, pickle (True, result) or (False,
    exception) to the original stdout (fd 1 goes to stderr, so that nothing else writes into the replies)."""
    requests, replies = sys.stdin.buffer, os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    try:
        pickle.dump((True, None), replies)  # started (`_Worker.ready`)
        replies.flush()
        while True:
            try:
                fn, args = pickle.load(requests)
            except EOFError:
                return
            try:
                reply = (True, fn(*args))
            except Exception as exc:  # noqa: BLE001 - handed to the caller
                reply = (False, exc)
            pickle.dump(reply, replies, protocol=pickle.HIGHEST_PROTOCOL)
            replies.flush()
    except BrokenPipeError:  # the parent is gone (a short run may end before the worker has started): no one to tell
        os._exit(0)
