"""ORB extraction, stereo matching and descriptor matching (dynaslam2.features)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynaslam2.config import ORBConfig, StereoConfig, load_config
from dynaslam2.errors import InputError
from dynaslam2.features import (
    Keypoints,
    ORBExtractor,
    depth_from_image,
    hamming_distance,
    hamming_indexed,
    hamming_pairs,
    match_descriptors,
    match_stereo,
    search_by_projection,
)
from dynaslam2.features.matcher import _pairs_in_radius, rotation_consistent
from dynaslam2.features.orb import base_to_level, level_scales, level_to_base
from dynaslam2.features.stereo import instance_disparities, search_stereo_rows
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.io.types import FrameData
from dynaslam2.tracking.box_association import instance_boxes
from dynaslam2.tracking.frontend import FrameBuilder

KITTI = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti-odometry-06"


def _kitti(name: str) -> np.ndarray:
    path = KITTI / name / "000000.png"
    if not path.exists():
        pytest.skip(f"real KITTI odometry 06 data absent: {path}")
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def _kitti_camera(shape) -> StereoCamera:
    rows = {}
    for line in (KITTI / "calib.txt").read_text().splitlines():
        key, _, vals = line.partition(":")
        rows[key.strip()] = np.array(vals.split(), float)
    return StereoCamera.from_projection_matrices(rows["P0"], rows["P1"], shape[1], shape[0])


@pytest.fixture(scope="module")
def extractor() -> ORBExtractor:
    return ORBExtractor(ORBConfig())


@pytest.fixture(scope="module")
def kitti_left(extractor):
    img = _kitti("image_0")
    pyr = extractor.build_pyramid(img)
    return img, pyr, extractor.extract(pyr)


def _occupied_fraction(uv: np.ndarray, shape, n: int, skip_top_rows: int = 0) -> float:
    """Fraction of an n x n grid's cells (minus the top rows) holding at least one keypoint."""
    h, w = shape
    cx = np.minimum((uv[:, 0] * n / w).astype(int), n - 1)
    cy = np.minimum((uv[:, 1] * n / h).astype(int), n - 1)
    occ = np.zeros((n, n), bool)
    occ[cy, cx] = True
    return occ[skip_top_rows:].mean()


def test_extraction_count_levels_and_types(kitti_left, extractor):
    img, pyr, kp = kitti_left
    n = extractor.cfg.n_features
    assert 0.95 * n <= len(kp) <= n
    assert set(np.unique(kp.octave)) == set(range(extractor.cfg.n_levels))
    counts = np.bincount(kp.octave, minlength=extractor.cfg.n_levels)
    assert np.all(np.diff(counts) < 0), counts  # geometric series: fewer features at coarser levels
    assert kp.uv.dtype == np.float32 and kp.uv.shape == (len(kp), 2)
    assert kp.desc.dtype == np.uint8 and kp.desc.shape == (len(kp), 32)
    assert kp.octave.dtype == np.int32 and kp.angle.dtype == np.float32 and kp.response.dtype == np.float32
    assert np.all((kp.angle >= 0) & (kp.angle < 360))
    assert np.all(kp.response >= extractor.cfg.min_th_fast)
    edge = extractor.cfg.edge_threshold
    assert kp.uv[:, 0].min() >= edge and kp.uv[:, 0].max() <= img.shape[1] - edge
    assert len(kp.subset(kp.octave == 0)) == counts[0]


def test_extraction_spreads_over_image_unlike_plain_orb(kitti_left):
    img, _, kp = kitti_left
    assert _occupied_fraction(kp.uv, img.shape, 4) == 1.0
    plain = cv2.ORB_create(nfeatures=len(kp)).detect(img)
    plain_uv = cv2.KeyPoint.convert(plain)
    ours_fine = _occupied_fraction(kp.uv, img.shape, 16, skip_top_rows=2)
    plain_fine = _occupied_fraction(plain_uv, img.shape, 16, skip_top_rows=2)
    assert ours_fine >= 0.9
    assert ours_fine > plain_fine + 0.1, (ours_fine, plain_fine)


@pytest.mark.parametrize("masked", [None, "blob", "hole", "boxes"])
def test_detection_equals_orbslam2_per_cell_rule(kitti_left, extractor, masked):
    """The candidates are exactly ORB-SLAM2's rule computed from one FAST pass at min_th_fast: a cell
    keeps its corners scoring >= ini_th_fast, or all its corners where it has none. With a mask, the
    rule applies to the corners whose nearest level-0 pixel is usable (with the mask's integral image, FAST
    runs only around the cells that hold one: "hole", the blob as the only usable part; "boxes", two small
    usable boxes as the dynamic instances of a frame)."""
    cfg = extractor.cfg
    fast = cv2.FastFeatureDetector_create(cfg.min_th_fast, True)
    img0, pyr, _ = kitti_left
    mask = None
    if masked in ("blob", "hole"):  # a blob of unusable pixels that empties some cells and cuts through others
        yy, xx = np.mgrid[0 : img0.shape[0], 0 : img0.shape[1]]
        mask = (xx - 500.0) ** 2 + ((yy - 200.0) * 2.5) ** 2 > 230.0**2
        mask = ~mask if masked == "hole" else mask
    elif masked == "boxes":
        mask = np.zeros(img0.shape, bool)
        mask[150:230, 301:377] = mask[40:52, 900:907] = True
    scales = level_scales(pyr)
    n_fallback = 0
    for level in range(len(pyr)):  # all levels: the last cells of a row or column reach past the edge
        img = pyr[level]
        h, w = img.shape
        kps = fast.detect(img)
        xy = cv2.KeyPoint.convert(kps)
        score = np.array([k.response for k in kps], np.float32)
        e = cfg.edge_threshold
        inside = (xy[:, 0] >= e) & (xy[:, 0] < w - e) & (xy[:, 1] >= e) & (xy[:, 1] < h - e)
        xy, score = xy[inside], score[inside]
        if masked:
            uv = np.rint(level_to_base(xy.astype(np.float64), scales[level])).astype(int)
            usable = mask[np.clip(uv[:, 1], 0, img0.shape[0] - 1), np.clip(uv[:, 0], 0, img0.shape[1] - 1)]
            xy, score = xy[usable], score[usable]
        n_cx, n_cy = (w - 2 * (e - 3)) // cfg.cell_size, (h - 2 * (e - 3)) // cfg.cell_size
        cw, ch = int(np.ceil((w - 2 * (e - 3)) / n_cx)), int(np.ceil((h - 2 * (e - 3)) / n_cy))
        cell = np.minimum((xy[:, 1].astype(int) - e) // ch, n_cy - 1) * n_cx + np.minimum((xy[:, 0].astype(int) - e) // cw, n_cx - 1)
        strong = score >= cfg.ini_th_fast
        keep = strong | ~np.isin(cell, cell[strong])
        n_fallback += (~strong & keep).sum()
        expected = {(x, y, s) for (x, y), s in zip(xy[keep].tolist(), score[keep].tolist())}
        mask_sum = None if masked in (None, "blob") else cv2.integral(mask.view(np.uint8))
        _, _, got_xy, got_score = extractor._detect(img, scales[level], mask, mask_sum)
        assert {(x, y, s) for (x, y), s in zip(got_xy.tolist(), got_score.tolist())} == expected
    assert n_fallback > 0  # the test covers cells that fall back to min_th_fast


def _gaussian_dots(shape, centres, sigmas) -> np.ndarray:
    """uint8 image: dark background with bright isotropic Gaussian dots at sub-pixel level-0 centres."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    img = np.full(shape, 40.0)
    for (cu, cv), sigma in zip(centres, sigmas):
        img += 200.0 * np.exp(-((xx - cu) ** 2 + (yy - cv) ** 2) / (2.0 * sigma**2))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_level_mapping_follows_the_pyramid_resampling(extractor):
    """A smooth blob at a known sub-pixel level-0 position: its intensity centroid on every level, mapped
    with `level_to_base` (pixel centres, actual level sizes), lands on the true position within 0.1 px;
    the nominal x_l * 1.2**l is off by ~0.5 * (1.2**l - 1) (1.3 px at level 7)."""
    truth = np.array([311.37, 237.81])
    img = _gaussian_dots((480, 640), [truth], [12.0])
    pyr = extractor.build_pyramid(img)
    scales = level_scales(pyr)
    assert scales.shape == (8, 2) and np.abs(scales[:, 0] / extractor.scale_factors - 1).max() < 3e-3
    nominal_err = []
    for level, p in enumerate(pyr):
        weight = np.maximum(p.astype(np.float64) - 40.0, 0.0)
        yy, xx = np.mgrid[0 : p.shape[0], 0 : p.shape[1]]
        centroid = np.array([(weight * xx).sum(), (weight * yy).sum()]) / weight.sum()
        uv = level_to_base(centroid, scales[level])
        assert np.abs(uv - truth).max() < 0.1, (level, uv, truth)
        np.testing.assert_allclose(base_to_level(uv, scales[level]), centroid, atol=1e-9)
        nominal_err.append(np.abs(centroid * extractor.scale_factors[level] - truth).max())
    assert nominal_err[-1] > 1.0, nominal_err


@pytest.mark.parametrize("level", range(8))
def test_keypoint_uv_is_the_level_pixel_centre_in_level_0(extractor, level):
    """A bright dot placed so that it is centred on a pixel of `level` (level-0 position from the actual
    level size): FAST finds it there at that level and its reported uv is the true level-0 position
    within 0.3 px at every level."""
    shape = (480, 640)
    pyr_shapes = [p.shape for p in extractor.build_pyramid(np.zeros(shape, np.uint8))]
    h_l, w_l = pyr_shapes[level]
    scale_xy = np.array([shape[1] / w_l, shape[0] / h_l])
    # Dots a dozen level pixels apart (7 each way in the interior), each on a level pixel centre.
    cols = np.rint(np.linspace(0.3, 0.7, 5) * w_l)
    rows = np.rint(np.linspace(0.3, 0.7, 5) * h_l)
    xy_level = np.stack(np.meshgrid(cols, rows), -1).reshape(-1, 2)
    truth = level_to_base(xy_level, scale_xy)
    s = extractor.scale_factors[level]
    img = _gaussian_dots(shape, truth, np.full(len(truth), 0.8 * s))
    kp = extractor.extract(extractor.build_pyramid(img))
    uv = kp.uv[kp.octave == level].astype(np.float64)
    assert len(uv) >= len(truth), (level, len(uv))
    err = np.linalg.norm(uv[:, None, :] - truth[None, :, :], axis=2).min(axis=0)
    assert np.all(err < 0.3), (level, err)


def test_extraction_deterministic(kitti_left, extractor):
    img, _, kp = kitti_left
    kp2 = extractor.extract(extractor.build_pyramid(img.copy()))
    for name in ("uv", "octave", "angle", "response", "desc"):
        np.testing.assert_array_equal(getattr(kp, name), getattr(kp2, name))


def test_describe_recomputes_the_extracted_orientation_and_descriptors(kitti_left, extractor):
    """`describe` on the same pyramid gives back `extract`'s angles and descriptors exactly, on every level."""
    _, pyr, kp = kitti_left
    idx = np.arange(len(kp))[::3]
    angle, desc = extractor.describe(pyr, kp, idx)
    assert len(np.unique(kp.octave[idx])) == extractor.n_levels
    np.testing.assert_array_equal(angle, kp.angle[idx])
    np.testing.assert_array_equal(desc, kp.desc[idx])


def test_extract_reports_stage_timings(kitti_left, extractor):
    _, pyr, kp = kitti_left
    timing: dict[str, float] = {}
    kp2 = extractor.extract(pyr, timing_ms=timing)
    assert set(timing) == {"fast", "spread", "orientation", "descriptors"}
    assert all(v > 0 for v in timing.values()), timing
    np.testing.assert_array_equal(kp2.desc, kp.desc)


@pytest.mark.parametrize("worker", ["process", "thread"])
def test_extract_pair_threads_and_budget_override(kitti_left, worker):
    img, pyr, kp = kitti_left
    pyr_r = ORBExtractor(ORBConfig()).build_pyramid(_kitti("image_1"))
    seq = ORBExtractor(ORBConfig(threads=1)).extract_pair(pyr, pyr_r, n_features_right=3000)
    parallel = ORBExtractor(ORBConfig(threads=2, worker=worker))
    first = parallel.extract_pair(pyr, pyr_r, n_features_right=3000)  # a process worker starts meanwhile
    assert parallel.start_worker(wait=True)
    par = parallel.extract_pair(pyr, pyr_r, n_features_right=3000)
    for a, b, c in zip(seq, first, par):
        for name in ("uv", "octave", "angle", "response", "desc"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
            np.testing.assert_array_equal(getattr(a, name), getattr(c, name))
    with pytest.raises(InputError):  # the worker's error reaches the caller; the worker still serves
        parallel.extract_pair(pyr, pyr_r, n_features_right=0)
    with pytest.raises(InputError):  # an error on the left image while the worker does the right one
        parallel.extract_pair(pyr, pyr_r, np.ones((10, 10), bool))
    np.testing.assert_array_equal(parallel.extract_pair(pyr, pyr_r)[1].desc, ORBExtractor(ORBConfig()).extract(pyr_r).desc)
    np.testing.assert_array_equal(seq[0].desc, kp.desc)
    assert 0.95 * 3000 <= len(seq[1]) <= 3000
    with pytest.raises(InputError):
        ORBExtractor(ORBConfig()).extract(pyr, n_features=0)


def test_extraction_max_level_drops_the_upper_budgets(kitti_left, extractor):
    """`max_level` keeps the budgets (and keypoints) of levels 0..max_level only, the same keypoints there."""
    _, pyr, full = kitti_left
    low = extractor.extract(pyr, max_level=2)
    assert low.octave.max() == 2
    keep = full.octave <= 2
    np.testing.assert_array_equal(full.uv[keep], low.uv)
    np.testing.assert_array_equal(full.desc[keep], low.desc)


def test_extraction_mask_drops_and_reallocates(kitti_left, extractor):
    img, pyr, kp = kitti_left
    mask = np.ones(img.shape, bool)
    mask[:, : img.shape[1] // 2] = False
    kp_m = extractor.extract(pyr, mask)
    assert kp_m.uv[:, 0].min() >= img.shape[1] // 2 - 1
    assert len(kp_m) > 0.9 * len(kp)  # the budget moves to the usable half
    with pytest.raises(InputError):
        extractor.extract(pyr, mask[:10])


def test_orientation_makes_descriptors_rotation_invariant(kitti_left, extractor):
    """Features of the image rotated by 90 degrees match the original at the rotated positions
    (needs the intensity-centroid angle and OpenCV keeping provided angles)."""
    img, _, kp = kitti_left
    rot = cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE)  # (x, y) -> (h-1-y, x)
    kp_r = extractor.extract(extractor.build_pyramid(rot))
    matches = match_descriptors(kp.desc, kp_r.desc, th=50, nn_ratio=0.8)
    expected = np.stack([img.shape[0] - 1 - kp.uv[:, 1], kp.uv[:, 0]], axis=1)
    err = np.linalg.norm(expected[matches[:, 0]] - kp_r.uv[matches[:, 1]], axis=1)
    good = err < 3.0 * ORBExtractor(ORBConfig()).scale_factors[kp.octave[matches[:, 0]]]
    assert good.sum() > 200 and good.mean() > 0.9, (len(matches), good.mean())


def test_rgb_input_and_bad_input(extractor):
    rgb = np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    pyr = extractor.build_pyramid(rgb)
    assert pyr[0].shape == (120, 160)
    with pytest.raises(InputError):
        extractor.build_pyramid(np.zeros((10, 10), np.float32))


def test_stereo_kitti_against_dense_reference(kitti_left, extractor):
    img_l, pyr_l, kp_l = kitti_left
    img_r = _kitti("image_1")
    camera = _kitti_camera(img_l.shape)
    pyr_r = extractor.build_pyramid(img_r)
    kp_r = extractor.extract(pyr_r)
    u_right, depth = match_stereo(kp_l, kp_r, pyr_l, pyr_r, camera, extractor.scale_factors, StereoConfig())
    has = depth > 0
    assert has.mean() >= 0.4, has.mean()
    assert np.all(u_right[~has] == -1)
    np.testing.assert_allclose(camera.bf / depth[has], kp_l.uv[has, 0] - u_right[has], atol=1e-3)  # float32 u
    sgbm = cv2.StereoSGBM_create(0, 128, 5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10, mode=cv2.STEREO_SGBM_MODE_HH)
    ref = sgbm.compute(img_l, img_r).astype(np.float32) / 16.0
    u, v = np.rint(kp_l.uv[has]).astype(int).T
    ref_d = ref[v, u]
    valid = ref_d > 0
    err = np.abs(kp_l.uv[has, 0] - u_right[has] - ref_d)[valid]
    assert valid.sum() > 300
    assert np.median(err) < 0.5, np.median(err)
    # `split`: two extraction passes in one call, each with its own SAD outlier test, as in two calls.
    a, b = slice(0, len(kp_l) // 3), slice(len(kp_l) // 3, len(kp_l))
    split = match_stereo(kp_l, kp_r, pyr_l, pyr_r, camera, extractor.scale_factors, StereoConfig(), split=a.stop)
    apart = [match_stereo(kp_l.subset(p), kp_r, pyr_l, pyr_r, camera, extractor.scale_factors, StereoConfig())
             for p in (a, b)]
    for got, first, second in zip(split, *apart):
        np.testing.assert_array_equal(got, np.r_[first, second])
    assert not np.array_equal(split[1], depth)  # the joint median differs on this pair


def _shifted_pair(disparity: float, shape=(240, 320), seed: int = 0):
    """Smooth random texture (left) and the same texture shifted left by `disparity` px (right)."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(0, 1, (shape[0], shape[1] + 64)).astype(np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), 1.5)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX)
    M = np.float32([[1, 0, -disparity], [0, 1, 0]])  # right(x) = left(x + d)
    right = cv2.warpAffine(tex, M, (tex.shape[1], tex.shape[0]), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    left, right = tex[:, 32:-32], right[:, 32:-32]
    return np.clip(np.rint(left), 0, 255).astype(np.uint8), np.clip(np.rint(right), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("disparity", [7.25, 12.5, 20.8])
def test_stereo_subpixel_on_shifted_texture(extractor, disparity):
    left, right = _shifted_pair(disparity)
    camera = StereoCamera(300.0, 300.0, 160.0, 120.0, 0.1, 320, 240)
    ex = ORBExtractor(ORBConfig(n_features=500))
    pyr_l, pyr_r = ex.build_pyramid(left), ex.build_pyramid(right)
    kp_l, kp_r = ex.extract(pyr_l), ex.extract(pyr_r)
    u_right, depth = match_stereo(kp_l, kp_r, pyr_l, pyr_r, camera, ex.scale_factors, StereoConfig())
    has = depth > 0
    assert has.sum() > 100
    err = np.abs(kp_l.uv[has, 0] - u_right[has] - disparity)
    assert np.median(err) < 0.15, np.median(err)
    assert np.mean(err < 1.0) > 0.95


@pytest.mark.parametrize("disparity", [7.25, 20.8])
def test_stereo_row_search_without_right_keypoints(disparity):
    """search_stereo_rows finds the disparity of left keypoints by their row alone (no right keypoint)."""
    left, right = _shifted_pair(disparity)
    camera = StereoCamera(300.0, 300.0, 160.0, 120.0, 0.1, 320, 240)
    ex = ORBExtractor(ORBConfig(n_features=500))
    pyr_l, pyr_r = ex.build_pyramid(left), ex.build_pyramid(right)
    kp_l = ex.extract(pyr_l)
    idx = np.flatnonzero(kp_l.uv[:, 0] > 60)  # the search range (up to 40 px) stays inside the right image
    u_right, depth = search_stereo_rows(kp_l, idx, pyr_l, pyr_r, camera, StereoConfig(), 0.75, 10.0)
    has = depth > 0
    assert has.mean() > 0.8, has.mean()
    err = np.abs(kp_l.uv[idx[has], 0] - u_right[has] - disparity)
    assert np.median(err) < 0.15, np.median(err)
    assert np.mean(err < 1.0) > 0.95
    np.testing.assert_allclose(depth[has], camera.bf / (kp_l.uv[idx[has], 0] - u_right[has]))


def test_stereo_row_search_rejects_repeated_texture():
    """On a texture repeating along the row every 9 px several disparities fit equally (level 0, where
    the repetition is exact): no depth (uniqueness test)."""
    rng = np.random.default_rng(1)
    period = np.clip(rng.normal(128, 60, (240, 9)), 0, 255)
    img = np.tile(period, (1, 36))[:, :320].astype(np.uint8)
    camera = StereoCamera(300.0, 300.0, 160.0, 120.0, 0.1, 320, 240)
    ex = ORBExtractor(ORBConfig(n_features=500))
    pyr = ex.build_pyramid(img)
    kp = ex.extract(pyr)
    idx = np.flatnonzero((kp.uv[:, 0] > 60) & (kp.octave == 0))
    assert len(idx) > 20
    _, depth = search_stereo_rows(kp, idx, pyr, pyr, camera, StereoConfig(), 0.75, 10.0)
    assert not np.any(depth > 0)


def _slanted_pair(slope: float, d0: float = 30.0, shape=(240, 320), seed: int = 0):
    """Road-marking-like texture (bright parallelograms on grey: corners with texture on one side) on a
    plane whose disparity grows `slope` px per row, as the ground does (baseline / camera height):
    right(x, v) = left(x + d0 + slope * (v - H/2), v)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    wide = w + 128
    tex = np.full((h, wide), 60, np.float32)
    for _ in range(120):
        x, y = rng.integers(0, wide), rng.integers(0, h)
        a, b = rng.integers(4, 25, 2)
        corners = np.array([[x, y], [x + a, y], [x + a + b // 2, y + b], [x + b // 2, y + b]], np.int32)
        cv2.fillConvexPoly(tex, corners, float(rng.uniform(90, 220)))
    tex = cv2.GaussianBlur(tex, (0, 0), 0.7) + rng.normal(0, 2, tex.shape).astype(np.float32)
    v = np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, wide))
    map_x = np.arange(wide, dtype=np.float32)[None, :] + d0 + slope * (v - h / 2)
    right = cv2.remap(tex, map_x.astype(np.float32), np.ascontiguousarray(v), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    crop = slice(64, 64 + w)
    return tuple(np.clip(np.rint(img[:, crop]), 0, 255).astype(np.uint8) for img in (tex, right))


def _slanted_errors(cfg: StereoConfig, slope: float) -> np.ndarray:
    """Disparity errors at keypoints on the slanted plane (3 seeds); the true disparity is taken at the
    keypoint's row, its level pixel centre mapped to level 0 (`level_to_base`)."""
    ex = ORBExtractor(ORBConfig(n_features=800))
    camera = StereoCamera(300.0, 300.0, 160.0, 120.0, 0.1, 320, 240)
    errors = []
    for seed in range(3):
        left, right = _slanted_pair(slope, seed=seed)
        pyr_l, pyr_r = ex.build_pyramid(left), ex.build_pyramid(right)
        kp_l, kp_r = ex.extract(pyr_l), ex.extract(pyr_r)
        u_right, depth = match_stereo(kp_l, kp_r, pyr_l, pyr_r, camera, ex.scale_factors, cfg)
        has = depth > 0
        errors.append(kp_l.uv[has, 0] - u_right[has] - (30.0 + slope * (kp_l.uv[has, 1] - 120.0)))
    return np.concatenate(errors)


def test_stereo_on_slanted_plane_keeps_corners_unbiased():
    """Ground-like slant (0.35 px/row): the default 11x5 SAD window keeps corner disparities within a
    pixel; ORB-SLAM2's 11x11 window shifts corners whose texture lies above or below them (measured:
    median |error| 0.88 px, 38% over 1 px), which biased stereo depth and the scale of simulated runs."""
    err = _slanted_errors(StereoConfig(), 0.35)
    assert len(err) > 1000
    assert np.median(np.abs(err)) < 0.4, np.median(np.abs(err))
    assert np.mean(np.abs(err) > 1.0) < 0.05, np.mean(np.abs(err) > 1.0)
    square = _slanted_errors(StereoConfig(sad_half_height=5), 0.35)
    assert np.mean(np.abs(square) > 1.0) > 4 * np.mean(np.abs(err) > 1.0)
    flat = _slanted_errors(StereoConfig(), 0.0)
    assert np.median(np.abs(flat)) < 0.05 and np.mean(np.abs(flat) > 0.5) < 0.01


@pytest.fixture(scope="module")
def rendered_street():
    """One rendered stereo frame of the simulated static street (640x480) and its camera."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    pytest.importorskip("mujoco")
    from sim.render import StereoRenderer
    from sim.scenarios import load_scenario
    from sim.world import build_world, camera_intrinsics

    cfg = load_scenario("static", ["frames=1", "image_size=640x480"])
    world = build_world(cfg)
    world.set_time(0.0)
    fx, fy, cx, cy = camera_intrinsics(cfg)
    width, height = cfg.image_size
    with StereoRenderer(world, width, height) as renderer:
        frame = renderer.render(world.ego_T_m_c(0.0), (fx, fy, cx, cy))
    return frame, StereoCamera(fx, fy, cx, cy, cfg.baseline, width, height)


def _rendered_disparity_errors(frame, camera, extractor, cfg: StereoConfig):
    """Signed disparity errors and true disparities at keypoints whose 5x5 neighbourhood has a smooth
    rendered depth (a corner on a depth edge has no single GT), and whether the keypoint is on level 0."""
    pyr_l, pyr_r = extractor.build_pyramid(frame.left), extractor.build_pyramid(frame.right)
    kp_l, kp_r = extractor.extract_pair(pyr_l, pyr_r)
    u_right, depth = match_stereo(kp_l, kp_r, pyr_l, pyr_r, camera, extractor.scale_factors, cfg)
    has = depth > 0
    assert has.mean() > 0.5, has.mean()
    u, v = np.rint(kp_l.uv[has]).astype(int).T
    z_gt = frame.depth.astype(np.float32)
    z_max = cv2.dilate(z_gt, np.ones((5, 5), np.uint8))
    z_min = -cv2.dilate(-np.where(z_gt > 0, z_gt, np.float32(1e9)), np.ones((5, 5), np.uint8))
    smooth = (z_gt[v, u] > 0) & (z_max[v, u] < 1.05 * z_min[v, u])
    assert smooth.sum() > 500
    d_gt = camera.bf / z_gt[v, u][smooth]
    err = (kp_l.uv[has, 0] - u_right[has])[smooth] - d_gt
    return err, d_gt, kp_l.octave[has][smooth] == 0


def test_stereo_on_rendered_pair_against_ground_truth_depth(rendered_street, extractor):
    """Simulated street (static scenario, 640x480): disparities at keypoints vs the rendered metric depth."""
    err, _, level0 = _rendered_disparity_errors(*rendered_street, extractor, StereoConfig())
    err = np.abs(err)
    assert np.median(err) < 0.25, np.median(err)
    assert np.median(err[level0]) < 0.15, np.median(err[level0])
    assert np.mean(err < 1.0) > 0.9, np.mean(err < 1.0)


def _locking_bias(err: np.ndarray, d_gt: np.ndarray) -> np.ndarray:
    """Median signed error of the keypoints whose true disparity has a fractional part in [0.2, 0.4) and
    in [0.6, 0.8): a fit pulled towards whole pixels errs negative, then positive."""
    frac = d_gt % 1.0
    return np.array([np.median(err[(frac >= lo) & (frac < lo + 0.2)]) for lo in (0.2, 0.6)])


def test_stereo_subpixel_fit_has_no_pixel_locking(rendered_street, extractor):
    """Level-0 keypoints of the rendered street: the equiangular fit's error does not depend on where the
    true disparity falls between whole pixels; the parabola's (ORB-SLAM2) is pulled towards them."""
    err, d_gt, level0 = _rendered_disparity_errors(*rendered_street, extractor, StereoConfig())
    bias = _locking_bias(err[level0], d_gt[level0])
    assert np.all(np.abs(bias) < 0.04), bias
    err_p, d_gt_p, level0_p = _rendered_disparity_errors(*rendered_street, extractor, StereoConfig(subpixel="parabola"))
    bias_p = _locking_bias(err_p[level0_p], d_gt_p[level0_p])
    assert bias_p[0] < -0.06 and bias_p[1] > 0.06, bias_p


def test_stereo_rejects_mismatched_sizes(extractor):
    a = extractor.build_pyramid(np.zeros((100, 120), np.uint8))
    b = extractor.build_pyramid(np.zeros((100, 130), np.uint8))
    camera = StereoCamera(100.0, 100.0, 60.0, 50.0, 0.1, 120, 100)
    kp = Keypoints.empty()
    with pytest.raises(InputError):
        match_stereo(kp, kp, a, b, camera, extractor.scale_factors, StereoConfig())


def test_depth_from_image():
    camera = StereoCamera(500.0, 500.0, 50.0, 40.0, 0.08, 100, 80)
    depth = np.zeros((80, 100), np.float32)
    depth[10, 20] = 2.0
    depth[30, 40] = np.nan
    kp = Keypoints.empty()
    kp.uv = np.array([[20.2, 9.8], [40, 30], [60, 60]], np.float32)
    u_right, z = depth_from_image(kp, depth, camera)
    np.testing.assert_allclose(z, [2.0, -1, -1])
    np.testing.assert_allclose(u_right, [20.2 - 40.0 / 2.0, -1, -1], rtol=1e-5)


def test_hamming_equals_naive_reference():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, (37, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    naive = np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=2).sum(axis=2)
    np.testing.assert_array_equal(hamming_distance(a, b), naive)
    assert hamming_distance(a, b).dtype == np.int32
    np.testing.assert_array_equal(hamming_pairs(a, b[:37]), naive[np.arange(37), np.arange(37)])
    assert hamming_distance(a[:0], b).shape == (0, 300)
    # indexed pairs, with repeats and the 256-bit extreme (all bits differ: past the uint8 of bitwise_count)
    b[5] = ~a[3]
    naive = np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=2).sum(axis=2)
    ia, ib = rng.integers(0, 37, 500), rng.integers(0, 300, 500)
    ia[0], ib[0] = 3, 5
    dist = hamming_indexed(a, b, ia, ib)
    np.testing.assert_array_equal(dist, naive[ia, ib])
    assert dist.dtype == np.int32 and dist[0] == 256


def test_match_descriptors_recovers_permutation():
    rng = np.random.default_rng(2)
    a = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    perm = rng.permutation(200)
    b = a[perm].copy()
    flips = rng.integers(0, 32, (200, 3))  # a few flipped bits
    b[np.arange(200)[:, None], flips] ^= 1
    m = match_descriptors(a, b, th=50, nn_ratio=0.8)
    assert len(m) == 200
    np.testing.assert_array_equal(perm[m[:, 1]], m[:, 0])


def test_rotation_consistency_keeps_three_main_bins():
    rng = np.random.default_rng(3)
    rot = np.concatenate([rng.uniform(-5, 5, 100), rng.uniform(91, 101, 30), rng.uniform(-173, -163, 12), rng.uniform(0, 360, 5)])
    keep = rotation_consistent(rot)
    assert keep[:142].all()  # bins 0, 8 and 16 (12 degrees each, centred on multiples of 12)
    assert not rotation_consistent(np.r_[np.full(100, 5.0), np.full(9, 180.0)])[100:].any()  # < 10% of the top


@pytest.mark.parametrize("n_query, r_max", [(40, 3.0), (800, 40.0)])  # few queries in a fine grid / many in a coarse one
def test_pairs_in_radius_equals_brute_force(n_query, r_max):
    """All (query, keypoint) pairs in the square and octave range, in the order of the grid walk (both ways
    of finding a cell's run: binary searches when the key table would be much larger than the queried cells)."""
    rng = np.random.default_rng(3)
    uv_kp = rng.uniform(0, [1226, 370], (2000, 2))
    octave = rng.integers(0, 8, 2000)
    uv_q = rng.uniform(-10, [1236, 380], (n_query, 2))
    radius = rng.uniform(1.0, r_max, n_query)
    lo = rng.integers(-1, 8, n_query)
    rng_oct = np.stack([lo, lo + rng.integers(0, 3, n_query)], axis=1)
    q, k = _pairs_in_radius(uv_kp, uv_q, radius, octave, rng_oct)
    inside = np.all(np.abs(uv_kp[None] - uv_q[:, None]) < radius[:, None, None], axis=2)
    inside &= (octave[None] >= rng_oct[:, :1]) & (octave[None] <= rng_oct[:, 1:])
    ref_q, ref_k = np.nonzero(inside)
    assert len(q) == len(ref_q) > 0
    order = np.lexsort((k, q))
    np.testing.assert_array_equal(q[order], ref_q)
    np.testing.assert_array_equal(k[order], ref_k)
    assert np.all(np.diff(q) >= 0)  # grouped by query


def test_search_by_projection_recovers_shift(kitti_left, extractor):
    """Keypoints of a shifted copy of the image are found from the original ones projected with the shift."""
    img, _, kp = kitti_left
    shift = np.array([6.0, -4.0])
    M = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    moved = cv2.warpAffine(img, M, (img.shape[1], img.shape[0]), borderMode=cv2.BORDER_REFLECT)
    kp2 = extractor.extract(extractor.build_pyramid(moved))
    uv_proj = kp.uv + shift + 0.7  # a small prediction error
    radius = 4.0 * extractor.scale_factors[kp.octave]
    octave_range = np.stack([kp.octave - 1, kp.octave + 1], axis=1)
    idx = search_by_projection(kp2, uv_proj, kp.desc, radius, octave_range, None, None, 100, 0.9, True, kp.angle)
    found = idx >= 0
    # Keypoints re-detected at the shifted position (same octave) are the true correspondences.
    dist = np.linalg.norm((kp.uv + shift)[:, None, :] - kp2.uv[None, :, :], axis=2)
    nearest = dist.argmin(axis=1)
    exists = (dist.min(axis=1) < 1.0) & (kp2.octave[nearest] == kp.octave)
    assert exists.sum() > 300
    assert (found & exists).sum() > 0.9 * exists.sum(), (found & exists).sum() / exists.sum()
    assert np.mean(idx[found & exists] == nearest[found & exists]) > 0.97
    err = np.abs(kp2.uv[idx[found]] - uv_proj[found])
    assert np.all(err < radius[found, None])
    assert len(np.unique(idx[found])) == found.sum()  # one keypoint per map point
    # The stereo check removes candidates with an inconsistent right coordinate.
    u_r_kp = kp2.uv[:, 0] - 10.0
    idx_bad = search_by_projection(
        kp2, uv_proj, kp.desc, radius, octave_range, uv_proj[:, 0] - 10.0 + 50.0, u_r_kp, 100, 0.9, False
    )
    assert np.all(idx_bad == -1)
    # Unavailable keypoints are never returned.
    available = np.ones(len(kp2), bool)
    available[idx[found]] = False
    idx_av = search_by_projection(kp2, uv_proj, kp.desc, radius, octave_range, None, None, 100, 0.9, False, available=available)
    assert not np.any(np.isin(idx_av[idx_av >= 0], idx[found]))
    # Non-finite projections (points behind the camera) match nothing and do not warn.
    uv_bad = uv_proj.copy()
    uv_bad[:5] = np.nan
    with np.errstate(all="raise"):
        idx_bad = search_by_projection(kp2, uv_bad, kp.desc, radius, octave_range, None, None, 100, 0.9, False)
    assert np.all(idx_bad[:5] == -1)


def test_search_by_projection_breaks_ties_by_keypoint_index():
    """Equally distant candidates go to the lower keypoint index, whatever other keypoints (e.g. the `dynamic`
    mode's object keypoints, unavailable to static points) shape the search grid."""
    desc = np.random.default_rng(0).integers(0, 256, (1, 32), dtype=np.uint8)

    def keypoints(uv):
        n = len(uv)
        return Keypoints(np.asarray(uv, np.float32), np.zeros(n, np.int32), np.zeros(n, np.float32),
                         np.ones(n, np.float32), np.repeat(desc, n, axis=0))

    twins = [[94.5, 101.0], [107.5, 101.0]]  # one descriptor, both 6.5 px from the projection
    for others in ([], [[3.0, 3.0], [90.0, 180.0], [300.0, 5.0]]):  # the others move the grid's cell borders
        for pair in (twins, twins[::-1]):
            kp = keypoints(pair + others)
            idx = search_by_projection(kp, np.array([[101.0, 101.0]]), desc, np.array([8.0]), None, None, None,
                                       50, 1.0, False, available=np.arange(len(kp)) < 2)
            assert idx[0] == 0, (others, pair)


def _narrow_objects_pair(d_bg: float = 6.0, d_obj: float = 15.0, width: int = 7, shape=(240, 320), seed: int = 0):
    """Narrow vertical objects (7 px wide, labels 2001, 2002, ...; a pedestrian at 15 m at 640x480) of one
    texture at disparity `d_obj` before a background of another texture at `d_bg`: (left, right, labels)."""
    rng = np.random.default_rng(seed)
    h, w = shape[0], shape[1] + 64

    def texture(sigma: float) -> np.ndarray:
        return cv2.normalize(cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), sigma), None, 0, 255,
                             cv2.NORM_MINMAX)

    background, objects = texture(1.5), texture(1.0)
    map_y = np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w))

    def shifted(img: np.ndarray, d: float, interpolation: int) -> np.ndarray:  # right(x) = left(x + d)
        return cv2.remap(img, np.tile(np.arange(w, dtype=np.float32) + d, (h, 1)), map_y, interpolation,
                         borderMode=cv2.BORDER_REFLECT)

    labels = np.zeros((h, w), np.int32)
    for k, x0 in enumerate(range(100, w - 24, 24)):
        labels[30 : h - 30, x0 : x0 + width] = 2001 + k
    left = np.where(labels > 0, objects, background)
    on_object = shifted(labels.astype(np.float32), d_obj, cv2.INTER_NEAREST) > 0
    right = np.where(on_object, shifted(objects, d_obj, cv2.INTER_CUBIC), shifted(background, d_bg, cv2.INTER_CUBIC))
    u8 = lambda a: np.clip(np.rint(a[:, 32:-32]), 0, 255).astype(np.uint8)  # noqa: E731
    return u8(left), u8(right), labels[:, 32:-32]


def test_stereo_row_search_on_narrow_objects_scores_their_own_pixels():
    """Keypoints on objects narrower than the SAD window, before a background at another disparity: scored
    on their instance's pixels only (`labels`), the row search finds the object's disparity for most of
    them; on the whole window the background's texture makes most of them fail the uniqueness test."""
    left, right, labels = _narrow_objects_pair()
    camera = StereoCamera(300.0, 300.0, 160.0, 120.0, 0.1, 320, 240)
    ex = ORBExtractor(ORBConfig(n_features=2000))
    pyr_l, pyr_r = ex.build_pyramid(left), ex.build_pyramid(right)
    kp = ex.extract(pyr_l)
    px = np.rint(kp.uv).astype(np.int64)
    idx = np.flatnonzero((labels[px[:, 1], px[:, 0]] > 0) & (kp.octave <= 1))
    assert len(idx) > 100
    correct = {}
    for name, lab in (("window", None), ("instance", labels)):
        u_right, depth = search_stereo_rows(kp, idx, pyr_l, pyr_r, camera, StereoConfig(), 0.75, 10.0, lab)
        has = depth > 0
        err = np.abs(kp.uv[idx[has], 0] - u_right[has] - 15.0)
        assert np.mean(err < 0.5) > 0.95, (name, np.mean(err < 0.5))
        correct[name] = int(np.sum(err < 0.5))
    assert correct["instance"] > 0.5 * len(idx), correct
    assert correct["instance"] > 3 * correct["window"], correct


@pytest.mark.parametrize("instance_sad", [True, False])
def test_dynamic_frames_give_narrow_objects_their_own_depth(instance_sad):
    """The `dynamic` mode's frame builder (default config: stereo.row_search_instance_mask) gives half the keypoints
    on objects narrower than the SAD window (a pedestrian at ~15 m at 640x480) the object's depth; scoring the
    whole window (False) gives far fewer of them one (`test_stereo_row_search_on_narrow_objects_...`)."""
    left, right, labels = _narrow_objects_pair()
    camera = StereoCamera(300.0, 300.0, 160.0, 120.0, 0.3, 320, 240)  # object 6 m, background 15 m
    overrides = ["mode=dynamic"] + ([] if instance_sad else ["stereo.row_search_instance_mask=false"])
    frame = FrameBuilder(load_config(None, overrides), camera).build(
        FrameData(0, 0.0, left, right, instances=labels.astype(np.uint16)), {})
    on = frame.instance_id > 0
    correct = np.abs(frame.depth[on] - 6.0) < 0.2
    assert on.sum() > 100
    assert (np.mean(correct) > 0.35 if instance_sad else np.mean(correct) < 0.2), np.mean(correct)  # 0.50 / 0.08


@pytest.mark.parametrize("d_obj", [11.3, 15.0])
def test_instance_disparities_match_each_mask_as_a_whole(d_obj):
    """Narrow objects (7 px wide: few keypoints each) before a background at another disparity: each instance's
    mask matched as a whole along its rows gives the object's disparity, sub-pixel, not the background's."""
    left, right, labels = _narrow_objects_pair(d_obj=d_obj)
    ids = np.unique(labels[labels > 0])
    d = instance_disparities(left, right, labels, ids, instance_boxes(labels, ids), 2.0, 40.0, 0.5, 0.8)
    assert len(ids) >= 8
    np.testing.assert_allclose(d, d_obj, atol=0.15)


def test_instance_disparities_reject_a_repeated_texture():
    """A texture repeating along the row every 9 px fits several disparities equally: no disparity (uniqueness);
    the same mask on a random texture gets one."""
    rng = np.random.default_rng(1)
    period = np.clip(rng.normal(128, 60, (240, 9)), 0, 255)
    img = np.tile(period, (1, 36))[:, :320].astype(np.uint8)
    labels = np.zeros(img.shape, np.int32)
    labels[60:180, 150:170] = 2001
    ids = np.array([2001])
    assert instance_disparities(img, img, labels, ids, instance_boxes(labels, ids), 2.0, 40.0, 0.5, 0.8)[0] == -1
    left, right = _shifted_pair(12.5)
    np.testing.assert_allclose(
        instance_disparities(left, right, labels, ids, instance_boxes(labels, ids), 2.0, 40.0, 0.5, 0.8), 12.5,
        atol=0.15)
