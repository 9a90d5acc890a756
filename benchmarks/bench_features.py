"""Median ms of ORB pyramid + extraction (left and right) and stereo matching.

    python benchmarks/bench_features.py [--repeat 15]

Images: the real KITTI odometry 06 pair (1226x370) from ../shared/data when present, and a
640x480 pair cut/resized from it (or a synthetic textured pair when KITTI is absent).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from dynaslam2.config import ORBConfig, StereoConfig
from dynaslam2.features import ORBExtractor, match_stereo
from dynaslam2.geometry.camera import StereoCamera

KITTI = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti-odometry-06"


def _pairs() -> list[tuple[str, np.ndarray, np.ndarray, StereoCamera]]:
    left_path, right_path = KITTI / "image_0" / "000000.png", KITTI / "image_1" / "000000.png"
    if left_path.exists():
        left = cv2.imread(str(left_path), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(right_path), cv2.IMREAD_GRAYSCALE)
    else:
        rng = np.random.default_rng(0)
        tex = cv2.GaussianBlur(rng.normal(0, 1, (370, 1290)).astype(np.float32), (0, 0), 2.0)
        tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
        left, right = tex[:, 40:1266], tex[:, 30:1256]
    fx, baseline = 707.09, 0.537
    h, w = left.shape
    kitti_cam = StereoCamera(fx, fx, w / 2, h / 2, baseline, w, h)
    # 640x480: stretch the KITTI pair (keeps rectification: rows stay rows).
    left_vga = cv2.resize(left, (640, 480), interpolation=cv2.INTER_AREA)
    right_vga = cv2.resize(right, (640, 480), interpolation=cv2.INTER_AREA)
    vga_cam = StereoCamera(fx * 640 / w, fx * 480 / h, 320.0, 240.0, baseline, 640, 480)
    return [(f"{w}x{h}", left, right, kitti_cam), ("640x480", left_vga, right_vga, vga_cam)]


def _median_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--n-features", type=int, default=2000)
    args = parser.parse_args()
    extractor = ORBExtractor(ORBConfig(n_features=args.n_features))
    stereo_cfg = StereoConfig()
    print(f"{'image':>10} {'pyramid':>8} {'extract':>8} {'stereo':>8} {'L+R+st':>8} {'n_kp':>6} {'depth%':>7}  (median ms, cv2 threads={cv2.getNumThreads()})")
    for name, left, right, camera in _pairs():
        pyr_l = extractor.build_pyramid(left)
        pyr_r = extractor.build_pyramid(right)
        kp_l, kp_r = extractor.extract(pyr_l), extractor.extract(pyr_r)
        t_pyr = _median_ms(lambda: extractor.build_pyramid(left), args.repeat)
        t_ext = _median_ms(lambda: extractor.extract(pyr_l), args.repeat)
        t_st = _median_ms(lambda: match_stereo(kp_l, kp_r, pyr_l, pyr_r, camera, extractor.scale_factors, stereo_cfg), args.repeat)
        _, depth = match_stereo(kp_l, kp_r, pyr_l, pyr_r, camera, extractor.scale_factors, stereo_cfg)
        total = 2 * (t_pyr + t_ext) + t_st
        print(f"{name:>10} {t_pyr:8.2f} {t_ext:8.2f} {t_st:8.2f} {total:8.2f} {len(kp_l):6d} {100 * np.mean(depth > 0):6.1f}%")


if __name__ == "__main__":
    main()
