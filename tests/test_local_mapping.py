"""Local mapping pieces (dynaslam2.mapping.local_mapping): epipolar candidate search and matching."""

from __future__ import annotations

import numpy as np
import pytest

from dynaslam2.features.matcher import hamming_distance, hamming_pairs, hamming_pairs_within
from dynaslam2.geometry.se3 import hat, make_pose, so3_exp
from dynaslam2.mapping.local_mapping import epipolar_matches, epipolar_pairs


def _flip_bits(desc: np.ndarray, n_bits: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Copies of `desc` with n_bits[i] distinct random bits of row i flipped."""
    bits = np.unpackbits(desc, axis=1)
    for i, n in enumerate(n_bits):
        bits[i, rng.choice(256, n, replace=False)] ^= 1
    return np.packbits(bits, axis=1)


def test_hamming_pairs_within_equals_the_full_distance():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    b = np.concatenate([_flip_bits(a[:200], rng.integers(0, 90, 200), rng), rng.integers(0, 256, (100, 32), dtype=np.uint8)])
    ia, ib = rng.integers(0, 300, 20000), rng.integers(0, 300, 20000)
    ia[:200], ib[:200] = np.arange(200), np.arange(200)  # the near copies
    full = hamming_pairs(a[ia], b[ib])
    for max_dist in (0, 20, 50, 100, 256):
        k, dist = hamming_pairs_within(a, b, ia, ib, max_dist)
        assert k.tolist() == np.flatnonzero(full <= max_dist).tolist()
        assert dist.tolist() == full[k].tolist()
    assert 50 < len(hamming_pairs_within(a, b, ia, ib, 50)[0]) < 200


def _two_views(t: list[float], rng: np.random.Generator):
    """K, T_2_1 (translation `t`), 800 + 900 random homogeneous pixels of a 1226x370 image pair and
    image-2 thresholds of random pyramid levels."""
    K = np.array([[700.0, 0, 600], [0, 710.0, 180], [0, 0, 1]])
    T_2_1 = make_pose(so3_exp(np.array([0.001, 0.01, 0.002])), np.array(t))
    x1 = np.column_stack([rng.uniform(0, 1226, 800), rng.uniform(0, 370, 800), np.ones(800)])
    x2 = np.column_stack([rng.uniform(0, 1226, 900), rng.uniform(0, 370, 900), np.ones(900)])
    th2 = 3.84 * 1.2 ** (2 * rng.integers(0, 8, 900))
    return K, T_2_1, x1, x2, th2


def _dense_near_line(K, T_2_1, x1, x2, th2) -> np.ndarray:
    """(N1, N2) bool: the dense epipolar-distance test of every pair."""
    K_inv = np.linalg.inv(K)
    L = x1 @ (K_inv.T @ hat(T_2_1[:3, 3]) @ T_2_1[:3, :3] @ K_inv).T
    return (L @ x2.T) ** 2 < th2[None, :] * (L[:, 0] ** 2 + L[:, 1] ** 2)[:, None]


@pytest.mark.parametrize("t", [[0.01, 0.02, -1.2], [1.0, 0.0, 0.05], [0.3, 0.1, 0.5], [0.0, 0.0, 1.0]])
def test_epipolar_pairs_equal_the_dense_test(t):
    """The pencil-window candidate search returns exactly the pairs of the dense N1 x N2 check."""
    K, T_2_1, x1, x2, th2 = _two_views(t, np.random.default_rng(3))
    a, b = epipolar_pairs(x1, x2, K, T_2_1, th2)
    A, B = np.nonzero(_dense_near_line(K, T_2_1, x1, x2, th2))
    assert len(A) > 1000
    assert sorted(zip(a.tolist(), b.tolist())) == sorted(zip(A.tolist(), B.tolist()))


@pytest.mark.parametrize("t", [[0.01, 0.02, -1.2], [1.0, 0.0, 0.05], [0.3, 0.1, 0.5]])
def test_epipolar_matches_equal_the_dense_tests(t):
    """Pairs near the epipolar line AND within the descriptor distance, as the dense N1 x N2 checks."""
    rng = np.random.default_rng(3)
    K, T_2_1, x1, x2, th2 = _two_views(t, rng)
    desc1 = rng.integers(0, 256, (800, 32), dtype=np.uint8)
    # Image-2 keypoints: noisy copies of random image-1 ones (some close); the first 300 are their
    # image-1 keypoint seen again (on its epipolar line), the rest lie anywhere.
    src = rng.integers(0, 800, 900)
    desc2 = _flip_bits(desc1[src], rng.integers(0, 120, 900), rng)
    X_2 = (rng.uniform(2, 50, (300, 1)) * x1[src[:300]] @ np.linalg.inv(K).T) @ T_2_1[:3, :3].T + T_2_1[:3, 3]
    x2[:300] = X_2 @ K.T / X_2[:, 2:]
    a, b, dist = epipolar_matches(x1, x2, K, T_2_1, th2, desc1, desc2, 50)
    D = hamming_distance(desc1, desc2)
    A, B = np.nonzero(_dense_near_line(K, T_2_1, x1, x2, th2) & (D <= 50))
    assert len(A) > 50
    assert sorted(zip(a.tolist(), b.tolist())) == sorted(zip(A.tolist(), B.tolist()))
    assert dist.tolist() == D[a, b].tolist()
