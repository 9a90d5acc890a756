"""Stereo / RGB-D depth for left keypoints (ORB-SLAM2's Frame::ComputeStereoMatches and
ComputeStereoFromRGBD, ref. [1]).

Stereo: right keypoints are candidates for a left keypoint when their row band (+-row_band_scale x
scale of their level) covers its row, their octave is within +-1, and the disparity is in
[0, bf / baseline]. The best descriptor distance must be < (th_high + th_low) / 2. It is refined by
a SAD search (+-sad_search px) on the keypoint's level image with a sub-pixel fit through the best
offset and its neighbours (level and level-0 coordinates mapped exactly, `level_to_base`: pixel centres
and the actual level sizes); matches with SAD > outlier_sad_factor x median SAD are dropped; depth =
bf / disparity.

Sub-pixel fit: ORB-SLAM2 fits a parabola, the model of a squared-difference cost. A SAD cost is
V-shaped around its minimum, and the parabola's vertex is pulled towards the integer offset ("pixel
locking"; Shimizu and Okutomi, 2001). The default fits the equiangular V instead (`subpixel`). Measured
on simulated streets (static s0 and traffic s1, 640x480, keypoints on smooth depth), the signed
disparity error binned by the fractional part of the true disparity: parabola -0.13 px at 0.2-0.4 and
+0.12 px at 0.6-0.8, equiangular within +-0.02 px; median |error| 0.12 -> 0.07 px on vehicles. The
locking does not average out on an object: the points of a distant vehicle share one disparity, so its
depth error is one bias of up to ~0.5 m at 25 m that jumps as the disparity crosses a fractional bin.

SAD window: 11 columns x 5 rows (ORB-SLAM2: 11x11). A window compares fronto-parallel patches, but on
the ground the disparity grows by ~baseline / camera height (~0.35 px) per row; a corner whose texture
lies on one side of its row (the end of a road marking) is then matched at the disparity of that
texture's mean row: with 11 rows up to ~1.5 px off, mostly too large (measured on simulated streets:
4.5% of near planar keypoints over +1 px, depth biased towards the camera, 0.4-0.6% scale drift).
5 rows cut that to ~1% (tests: slanted plane).

Brightness normalization: ORB-SLAM2 subtracts each patch's centre pixel (`sad_centre="pixel"`); the
default subtracts the patch mean ("mean"): the same offset invariance without the centre pixel's
noise. Sub-pixel error on shifted textures 0.04-0.10 px instead of 0.14-0.17 px, and about half the
median difference to SGBM on KITTI (0.22 vs 0.40 px).

Row search (`search_stereo_rows`, dynamic-class keypoints without a right keypoint): optionally
segmentation-aware, the window scored on the keypoint's own instance pixels only (`labels`).

Vectorized: (left, right) candidate pairs come from a (row, octave) index with numpy; SAD patches are
gathered per pyramid level and scored in one pass per search offset.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from dynaslam2.config import StereoConfig
from dynaslam2.errors import InputError
from dynaslam2.features.matcher import argsort_keys, hamming_indexed
from dynaslam2.features.orb import Keypoints, base_to_level, level_scales, level_to_base
from dynaslam2.geometry.camera import StereoCamera


def _row_candidates(kp_left: Keypoints, kp_right: Keypoints, n_rows: int, scale_factors, band: float):
    """(left, right) index pairs: the right keypoint's row band (+-band x its scale) covers the left
    keypoint's row and its octave is within +-1 of the left one. Right keypoints are bucketed by
    (row, octave), so the three octaves of a left keypoint's row are one contiguous run."""
    n_oct = int(max(kp_left.octave.max(), kp_right.octave.max())) + 1
    r = band * np.asarray(scale_factors)[kp_right.octave]
    v = kp_right.uv[:, 1].astype(np.float64)
    row_lo = np.clip(np.floor(v - r).astype(np.int64), 0, n_rows - 1)
    row_hi = np.clip(np.ceil(v + r).astype(np.int64), 0, n_rows - 1)
    n_rows_of = row_hi - row_lo + 1
    j = np.repeat(np.arange(len(kp_right)), n_rows_of)
    rows = np.repeat(row_lo, n_rows_of) + (np.arange(len(j)) - np.repeat(np.cumsum(n_rows_of) - n_rows_of, n_rows_of))
    key = rows * n_oct + kp_right.octave[j]
    order = argsort_keys(key, n_rows * n_oct)
    j = j[order]
    starts = np.searchsorted(key[order], np.arange(n_rows * n_oct + 1))
    row_left = np.clip(kp_left.uv[:, 1].astype(np.int64), 0, n_rows - 1) * n_oct
    first = starts[row_left + np.maximum(kp_left.octave - 1, 0)]
    count = starts[row_left + np.minimum(kp_left.octave + 1, n_oct - 1) + 1] - first
    i = np.repeat(np.arange(len(kp_left)), count)
    offs = np.arange(len(i)) - np.repeat(np.cumsum(count) - count, count)
    return i, j[np.repeat(first, count) + offs]


def _gather_patches(img_l, img_r, su_l, sv_l, su_r, w: int, h: int, L: int):
    """Left (K,2h+1,2w+1) patches and right (K,2h+1,2w+1+2L) strips around integer level coordinates;
    `ok` where inside."""
    rows, cols = img_l.shape
    ok = (sv_l - h >= 0) & (sv_l + h < rows) & (su_l - w >= 0) & (su_l + w < cols)
    ok &= (su_r - L - w >= 0) & (su_r + L + w < cols)
    idx = np.flatnonzero(ok)
    k, kh = 2 * w + 1, 2 * h + 1
    patch_l = sliding_window_view(img_l, (kh, k))[sv_l[idx] - h, su_l[idx] - w]
    strip = sliding_window_view(img_r, (kh, k + 2 * L))[sv_l[idx] - h, su_r[idx] - L - w]
    return ok, patch_l, strip


def _sad_curve(patch_l: np.ndarray, strip: np.ndarray, w: int, L: int, centre: str, n_rows=None,
               weight: np.ndarray | None = None) -> np.ndarray:
    """(K, 2L+1) SAD of the left (K,kh,k) patch against the right windows at offsets -L..L, both
    brightness-normalized by their centre pixel ("pixel", ORB-SLAM2) or their mean ("mean").
    `n_rows` ((2L+1,), optional): score only the first n_rows[o] keypoints at offset o, inf for the rest.
    `weight` ((K,kh,k) 0/1, optional): only the pixels of weight 1 count, in the sums and in the means
    that normalize the brightness (mean normalization whatever `centre`): a window on an object's pixels,
    its background left out."""
    K, kh = patch_l.shape[:2]
    k, n_off = 2 * w + 1, 2 * L + 1
    patch_l = patch_l.astype(np.float32)
    strip = strip.astype(np.float32)
    if weight is not None:
        return _sad_curve_weighted(patch_l, strip, weight.astype(np.float32), w, L, n_rows)
    if centre == "pixel":
        ref_l = patch_l[:, kh // 2, w]
        ref_r = strip[:, kh // 2, w : w + n_off]  # centre pixel of the window at each offset
    else:
        ref_l = patch_l.reshape(K, -1).mean(axis=1)
        col_sum = np.concatenate([np.zeros((K, 1), np.float32), np.cumsum(strip.sum(axis=1), axis=1)], axis=1)
        ref_r = (col_sum[:, k:] - col_sum[:, :-k]) / (kh * k)  # box mean of the window at each offset
    centred_l = patch_l - ref_l[:, None, None]
    rows_r = strip.reshape(K * kh, k + 2 * L)  # all strips stacked: offset o = columns o..o+k-1
    ref_r = np.ascontiguousarray(ref_r.T)[:, :, None, None]  # (2L+1, K, 1, 1)
    n_rows = np.full(n_off, K) if n_rows is None else n_rows
    dists = np.full((n_off, K, 1), np.inf, np.float32)
    target = np.empty((K, kh, k), np.float32)
    absdiff = np.empty((K * kh, k), np.float32)
    for o in range(n_off):  # loop over the 2L+1 offsets, vectorized (OpenCV) over keypoints, into buffers
        n = int(n_rows[o])
        if n == 0:
            continue
        np.add(centred_l[:n], ref_r[o, :n], out=target[:n])
        cv2.absdiff(rows_r[: n * kh, o : o + k], target[:n].reshape(n * kh, k), dst=absdiff[: n * kh])
        cv2.reduce(absdiff[: n * kh].reshape(n, kh * k), 1, cv2.REDUCE_SUM, dst=dists[o, :n])
    return dists[:, :, 0].T


def _sad_curve_weighted(patch_l: np.ndarray, strip: np.ndarray, weight: np.ndarray, w: int, L: int,
                        n_rows) -> np.ndarray:
    """`_sad_curve` with "mean" normalization over the pixels of `weight` 1 only."""
    K, kh, k = patch_l.shape
    n_off = 2 * L + 1
    wsum = np.maximum(weight.reshape(K, -1).sum(axis=1), 1.0)
    centred_l = (patch_l - ((weight * patch_l).reshape(K, -1).sum(axis=1) / wsum)[:, None, None]) * weight
    n_rows = np.full(n_off, K) if n_rows is None else n_rows
    dists = np.full((n_off, K), np.inf, np.float32)
    for o in range(n_off):
        n = int(n_rows[o])
        if n == 0:
            continue
        win = strip[:n, :, o : o + k] * weight[:n]
        ref_r = win.reshape(n, -1).sum(axis=1) / wsum[:n]
        win -= ref_r[:, None, None] * weight[:n]
        dists[o, :n] = np.abs(win - centred_l[:n]).reshape(n, -1).sum(axis=1)
    return dists.T


def _subpixel_minimum(dists: np.ndarray, L: int, fit: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Best offset (-L..L), sub-pixel delta of the `fit` ("equiangular" V or "parabola") through the best
    and its neighbours, best SAD, and `ok` (best not at the border of the search, finite vertex)."""
    best = np.argmin(dists, axis=1)
    interior = (best > 0) & (best < 2 * L)
    b = np.clip(best, 1, 2 * L - 1)
    rr = np.arange(len(dists))
    d1, d2, d3 = (dists[rr, b - 1].astype(np.float64), dists[rr, b].astype(np.float64), dists[rr, b + 1].astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        if fit == "equiangular":
            delta = (d1 - d3) / (2.0 * (np.maximum(d1, d3) - d2))
        else:
            delta = (d1 - d3) / (2.0 * (d1 + d3 - 2.0 * d2))
    ok = interior & np.isfinite(delta)
    return best - L, np.where(ok, delta, 0.0), dists[rr, best].astype(np.float64), ok


def match_stereo(
    kp_left: Keypoints,
    kp_right: Keypoints,
    pyr_left: list[np.ndarray],
    pyr_right: list[np.ndarray],
    camera: StereoCamera,
    scale_factors,
    cfg: StereoConfig,
    split: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Right-image u coordinate and depth (m) of each left keypoint; (N,) float32 each, -1 where none.
    `scale_factors` (nominal scale per level) sizes the row band; positions use the pyramids' sizes.
    `split`: the left keypoints before and from this index (two extraction passes) take the SAD outlier
    test against the median of their own matches, as if matched in two calls."""
    n = len(kp_left)
    u_right = np.full(n, -1.0, np.float32)
    depth = np.full(n, -1.0, np.float32)
    if pyr_left[0].shape != pyr_right[0].shape:
        raise InputError(f"stereo: left image {pyr_left[0].shape} and right image {pyr_right[0].shape} differ in size")
    if n == 0 or len(kp_right) == 0:
        return u_right, depth
    scale_factors = np.asarray(scale_factors, np.float64)
    bf = camera.bf
    min_d, max_d = 0.0, bf / camera.baseline  # min depth = one baseline

    i, j = _row_candidates(kp_left, kp_right, pyr_left[0].shape[0], scale_factors, cfg.row_band_scale)
    u_l = kp_left.uv[:, 0].astype(np.float64)
    u_r = kp_right.uv[:, 0].astype(np.float64)
    d_lr = u_l[i] - u_r[j]
    keep = (d_lr >= min_d) & (d_lr <= max_d)
    i, j = i[keep], j[keep]
    if len(i) == 0:
        return u_right, depth
    dist = hamming_indexed(kp_left.desc, kp_right.desc, i, j).astype(np.int64)
    # Pairs are grouped by left index: the best per group is the smallest (distance, right index) key,
    # i.e. ORB-SLAM2's first strict minimum over right keypoints in index order.
    starts = np.flatnonzero(np.r_[True, i[1:] != i[:-1]])
    n_right = len(kp_right)
    key = np.minimum.reduceat(dist * n_right + j, starts)
    i, j, best_dist = i[starts], key % n_right, key // n_right
    good = best_dist < min(cfg.th_high, (cfg.th_high + cfg.th_low) / 2.0)
    i, j = i[good], j[good]
    if len(i) == 0:
        return u_right, depth

    w, h, L = cfg.sad_window, cfg.sad_half_height, cfg.sad_search
    octave = kp_left.octave[i]
    scale_xy = level_scales(pyr_left)[octave]  # exact level <-> level-0 maps (actual level sizes)
    su_l = np.rint(base_to_level(u_l[i], scale_xy[:, 0])).astype(np.int64)
    sv_l = np.rint(base_to_level(kp_left.uv[i, 1].astype(np.float64), scale_xy[:, 1])).astype(np.int64)
    su_r = np.rint(base_to_level(u_r[j], scale_xy[:, 0])).astype(np.int64)
    order = argsort_keys(octave, len(scale_factors))  # gather level by level, then one SAD pass
    i, octave, su_l, sv_l, su_r, scale_xy = i[order], octave[order], su_l[order], sv_l[order], su_r[order], scale_xy[order]
    ok = np.zeros(len(i), bool)
    patches_l, strips = [], []
    for level in np.unique(octave):
        sel = slice(*np.searchsorted(octave, [level, level + 1]))
        ok_l, patch_l, strip = _gather_patches(pyr_left[level], pyr_right[level], su_l[sel], sv_l[sel], su_r[sel], w, h, L)
        ok[sel] = ok_l
        patches_l.append(patch_l)
        strips.append(strip)
    i, su_r, scale_u = i[ok], su_r[ok], scale_xy[ok, 0]
    if len(i) == 0:
        return u_right, depth
    dists = _sad_curve(np.concatenate(patches_l), np.concatenate(strips), w, L, cfg.sad_centre)
    inc, delta, sad, ok = _subpixel_minimum(dists, L, cfg.subpixel)
    ok &= np.abs(delta) <= cfg.max_subpixel_delta
    best_ur = level_to_base(su_r + inc + delta, scale_u)  # a level disparity scales by W / W_l
    disparity = u_l[i] - best_ur
    ok &= (disparity >= min_d) & (disparity < max_d)
    i, best_ur, disparity, sad = i[ok], best_ur[ok], disparity[ok], sad[ok]
    tiny = disparity <= 0
    disparity[tiny] = 0.01
    best_ur[tiny] = u_l[i[tiny]] - 0.01
    if len(i) == 0:
        return u_right, depth
    inlier = np.zeros(len(i), bool)
    for part in ((slice(None),) if split is None else (i < split, i >= split)):
        part_sad = sad[part]
        if len(part_sad):
            median = np.sort(part_sad)[len(part_sad) // 2]  # ORB-SLAM2 takes the upper median
            inlier[part] = part_sad <= cfg.outlier_sad_factor * median
    i, best_ur, disparity = i[inlier], best_ur[inlier], disparity[inlier]
    u_right[i] = best_ur
    depth[i] = bf / disparity
    return u_right, depth


def labels_at_level(labels: np.ndarray, level_shape: tuple[int, int], scale_xy: np.ndarray) -> np.ndarray:
    """The level-0 label image `labels` (HxW) sampled on a pyramid level of shape `level_shape` (exact scales
    `scale_xy`, `level_scales`): each level pixel takes the label of its nearest level-0 pixel."""
    (hl, wl), (H, W) = level_shape[:2], labels.shape
    rows = np.clip(np.rint(level_to_base(np.arange(hl), scale_xy[1])).astype(np.int64), 0, H - 1)
    cols = np.clip(np.rint(level_to_base(np.arange(wl), scale_xy[0])).astype(np.int64), 0, W - 1)
    return labels[rows][:, cols]


def search_stereo_rows(
    kp_left: Keypoints,
    idx: np.ndarray,
    pyr_left: list[np.ndarray],
    pyr_right: list[np.ndarray],
    camera: StereoCamera,
    cfg: StereoConfig,
    min_depth_m: float,
    max_depth_m: float,
    labels: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Right-image u and depth (m) of the left keypoints `idx` found by a SAD search along their row of
    the right image (no right keypoint needed), over the disparities of depths [min_depth_m,
    max_depth_m], on the keypoint's level; (len(idx),) float64 each, -1 where none. Same SAD window,
    brightness normalization and sub-pixel fit as `match_stereo`; a match needs its best SAD below
    row_search_uniqueness x the best SAD away from it (more than one px off: StereoBM's uniqueness
    test) and its sub-pixel vertex within max_subpixel_delta. For keypoints `match_stereo` left
    without depth because no right keypoint matched them (small, far objects).
    `labels` (HxW ints, level 0, optional): a keypoint on a label > 0 is scored on the pixels of its own
    label only (segmentation-aware SAD: the background around a narrow object, at another disparity,
    left out), and needs >= row_search_min_support of its window on them."""
    idx = np.asarray(idx, dtype=np.int64)
    u_right = np.full(len(idx), -1.0)
    depth = np.full(len(idx), -1.0)
    if len(idx) == 0:
        return u_right, depth
    w, h = cfg.sad_window, cfg.sad_half_height
    k, kh = 2 * w + 1, 2 * h + 1
    scales = level_scales(pyr_left)
    lv_lo, lv_hi = camera.bf / max_depth_m / scales[:, 0], camera.bf / min_depth_m / scales[:, 0]  # level disparities
    lv_L = np.ceil((lv_hi - lv_lo) / 2.0).astype(np.int64) + 1  # offsets -L..L around the level's mid disparity
    # One SAD pass for all levels over the widest range -L_max..L_max (a window's SAD does not depend on
    # the batch); offsets beyond a keypoint's own +-L are invalid (not scored: keypoints ordered by
    # decreasing L, each offset scores a prefix), which leaves the same best, neighbours and
    # away-minimum as a search over its level's range alone.
    order = np.argsort(-lv_L[kp_left.octave[idx]], kind="stable")
    octave = kp_left.octave[idx[order]]
    sx, sy = scales[octave].T
    d_lo, d_hi, L = lv_lo[octave], lv_hi[octave], lv_L[octave]
    u_l = kp_left.uv[idx[order], 0].astype(np.float64)
    su = np.rint(base_to_level(u_l, sx)).astype(np.int64)
    sv = np.rint(base_to_level(kp_left.uv[idx[order], 1].astype(np.float64), sy)).astype(np.int64)
    d_mid = np.rint((d_hi + d_lo) / 2.0).astype(np.int64)
    L_max = int(L.max())
    off = np.arange(2 * L_max + 1)
    first = su - d_mid - L_max  # right column of offset 0
    patch = np.empty((len(idx), kh, k), pyr_left[0].dtype)
    strip = np.empty((len(idx), kh, k + 2 * L_max), pyr_right[0].dtype)
    cols = np.empty(len(idx), np.int64)
    own = None
    if labels is not None:
        px = np.rint(kp_left.uv[idx[order]]).astype(np.int64)
        own = labels[np.clip(px[:, 1], 0, labels.shape[0] - 1), np.clip(px[:, 0], 0, labels.shape[1] - 1)]
        weight = np.ones((len(idx), kh, k), bool)
    for level in np.unique(octave).tolist():
        sel = np.flatnonzero(octave == level)
        pad = int(d_mid[sel[0]]) + L_max + w + 1  # every strip inside the padded images; offsets off the image masked
        right = cv2.copyMakeBorder(pyr_right[level], h, h, pad, pad, cv2.BORDER_REPLICATE)
        left = cv2.copyMakeBorder(pyr_left[level], h, h, w, w, cv2.BORDER_REPLICATE)
        patch[sel] = sliding_window_view(left, (kh, k))[sv[sel], su[sel]]  # padded: row sv - h + h, column su - w + w
        strip[sel] = sliding_window_view(right, (kh, k + 2 * L_max))[sv[sel], first[sel] - w + pad]
        cols[sel] = pyr_right[level].shape[1]
        if own is not None:
            lab = np.pad(labels_at_level(labels, pyr_left[level].shape, scales[level]), ((h, h), (w, w)))
            win = sliding_window_view(lab, (kh, k))[sv[sel], su[sel]]
            weight[sel] = (win == own[sel, None, None]) | (own[sel, None, None] <= 0)
    in_range = np.abs(off - L_max)[None] <= L[:, None]
    dists = _sad_curve(patch, strip, w, L_max, cfg.sad_centre, in_range.sum(axis=0),
                       weight if own is not None else None).astype(np.float64)
    col = first[:, None] + off[None]
    disp = su[:, None] - col
    valid = in_range & (col >= w) & (col < cols[:, None] - w)
    valid &= (disp >= d_lo[:, None] - 1) & (disp <= d_hi[:, None] + 1)
    dists[~valid] = np.inf
    inc, delta, sad, ok = _subpixel_minimum(np.where(valid, dists, 1e30), L_max, cfg.subpixel)
    best = inc + L_max
    rr = np.arange(len(idx))
    away = dists.copy()
    for o in (-1, 0, 1):
        away[rr, np.clip(best + o, 0, 2 * L_max)] = np.inf
    nb = valid[rr, np.clip(best - 1, 0, 2 * L_max)] & valid[rr, np.clip(best + 1, 0, 2 * L_max)]
    ok &= valid[rr, best] & nb & (sad < cfg.row_search_uniqueness * away.min(axis=1))
    ok &= np.abs(delta) <= cfg.max_subpixel_delta
    if own is not None:
        ok &= weight.reshape(len(idx), -1).mean(axis=1) >= cfg.row_search_min_support
    ur = level_to_base(first + best + delta, sx)
    disparity = u_l - ur
    ok &= disparity > 0
    u_right[order[ok]] = ur[ok]
    depth[order[ok]] = camera.bf / disparity[ok]
    return u_right, depth


def depth_from_image(kp_left: Keypoints, depth: np.ndarray, camera: StereoCamera) -> tuple[np.ndarray, np.ndarray]:
    """RGB-D: depth at the nearest pixel of each keypoint (<= 0 / non-finite -> -1) and the virtual
    right coordinate u - bf / depth (ORB-SLAM2's ComputeStereoFromRGBD). Returns (u_right, depth)."""
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise InputError(f"depth image: expected HxW metres, got shape {depth.shape}")
    h, w = depth.shape
    col = np.clip(np.rint(kp_left.uv[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(kp_left.uv[:, 1]).astype(np.int64), 0, h - 1)
    d = depth[row, col].astype(np.float64)
    valid = np.isfinite(d) & (d > 0)
    z = np.where(valid, d, -1.0).astype(np.float32)
    u_r = np.where(valid, kp_left.uv[:, 0] - camera.bf / np.where(valid, d, 1.0), -1.0).astype(np.float32)
    return u_r, z


def instance_disparities(gray_l: np.ndarray, gray_r: np.ndarray, instances: np.ndarray, ids: np.ndarray,
                         boxes: np.ndarray, d_min: float, d_max: float, min_ncc: float, uniqueness: float
                         ) -> np.ndarray:
    """(K,) disparity (px, level 0) of each instance `ids[k]` as a whole: its left mask (box `boxes[k]`: left,
    top, right, bottom) matched along its rows of the right image by normalized cross-correlation on the mask's
    pixels only (`cv2.matchTemplate`, TM_CCOEFF_NORMED with the mask), disparities d_min..d_max, with a
    parabola through the peak and its neighbours. -1 where the peak lies at the border of the search, its NCC is
    below `min_ncc`, or (1 - peak) is not below `uniqueness` x (1 - the best NCC more than 1 px away). A
    measurement that needs no keypoints: the instance's pixels all take part (a small or hidden object)."""
    out = np.full(len(ids), -1.0)
    width = gray_l.shape[1]
    for k, (inst, box) in enumerate(zip(np.asarray(ids).tolist(), boxes)):
        if not np.all(np.isfinite(box)):
            continue
        x0, y0, x1, y1 = (int(b) for b in box)
        lo, hi = max(int(np.floor(d_min)) - 1, 0), min(int(np.ceil(d_max)) + 1, x0)
        if hi - lo < 2 or x1 - x0 < 1 or y1 - y0 < 1:
            continue
        mask = (instances[y0:y1 + 1, x0:x1 + 1] == inst).astype(np.float32)
        templ = gray_l[y0:y1 + 1, x0:x1 + 1].astype(np.float32)
        strip = gray_r[y0:y1 + 1, x0 - hi:min(x1 - lo + 1, width)].astype(np.float32)
        if strip.shape[1] < templ.shape[1] + 2:
            continue
        ncc = cv2.matchTemplate(strip, templ, cv2.TM_CCOEFF_NORMED, mask=mask)[0][::-1]  # j: disparity hi - n + 1 + j
        ncc = np.where(np.isfinite(ncc), ncc, -1.0)
        j = int(np.argmax(ncc))
        if j == 0 or j == len(ncc) - 1 or ncc[j] < min_ncc:
            continue
        away = np.r_[ncc[:j - 1], ncc[j + 2:]]
        if len(away) and (1.0 - ncc[j]) >= uniqueness * (1.0 - away.max()):
            continue
        c1, c2, c3 = ncc[j - 1], ncc[j], ncc[j + 1]
        denom = c1 + c3 - 2.0 * c2
        delta = 0.5 * (c1 - c3) / denom if denom < 0 else 0.0
        out[k] = hi - len(ncc) + 1 + j + delta
    return out
