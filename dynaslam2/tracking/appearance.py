"""Appearance of the instances for object association (not in the paper; DeepSORT's appearance gallery): each
instance's colour histogram over its mask, and the Bhattacharyya distance of an instance to a track's gallery of
recent histograms (the nearest one). Side by side, two pedestrians' keypoints match each other's object points
(31 px ORB patches on a 12 px wide body reach onto the neighbour), their poses differ by one body width and their
boxes overlap; their clothes differ."""

from __future__ import annotations

import numpy as np


def instance_histograms(image: np.ndarray, instances: np.ndarray, ids: np.ndarray, bins: int,
                        min_pixels: int) -> np.ndarray:
    """(K, B) normalized colour histograms of the mask pixels of instance ids `ids`: `bins` per channel of an RGB
    image (B = bins^3), bins^2 intensity levels of a grey one; a row of NaN for an instance with fewer than
    `min_pixels` pixels (too few to judge its appearance). One pass over the image (a bincount)."""
    levels = (image.astype(np.int64) * bins) >> 8
    if image.ndim == 3:
        code, n_bins = (levels[..., 0] * bins + levels[..., 1]) * bins + levels[..., 2], bins**3
    else:
        code, n_bins = (image.astype(np.int64) * bins * bins) >> 8, bins * bins
    hist = np.full((len(ids), n_bins), np.nan)
    if not len(ids):
        return hist
    on = np.isin(instances, ids)
    k = np.searchsorted(ids, instances[on])
    counts = np.bincount(k * n_bins + code[on], minlength=len(ids) * n_bins).reshape(len(ids), n_bins)
    pixels = counts.sum(axis=1)
    enough = pixels >= min_pixels
    hist[enough] = counts[enough] / pixels[enough, None]
    return hist


def gallery_distance(hist: np.ndarray, gallery: list[np.ndarray]) -> np.ndarray:
    """(K,) Bhattacharyya distance (sqrt(1 - sum sqrt(p q)), 0 alike .. 1 disjoint) of each histogram of `hist` to
    its nearest one in `gallery`; NaN for a NaN row or an empty gallery (no evidence)."""
    if not gallery:
        return np.full(len(hist), np.nan)
    overlap = (np.sqrt(hist) @ np.sqrt(np.asarray(gallery)).T).max(axis=1)  # NaN rows stay NaN
    return np.sqrt(np.clip(1.0 - overlap, 0.0, 1.0))
