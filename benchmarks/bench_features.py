"""Median ms of ORB pyramid + extraction (left and right) and stereo matching.

    python benchmarks/bench_features.py [--repeat 15] [--right-factor 1.0] [--cv-threads N] [--sad-half-height H]

Images: the real KITTI odometry 06 pair (1226x370) from ../shared/data when present (else a synthetic
textured pair), and a rendered 640x480 frame of the simulated static street (else KITTI resized).
Each cell: median wall ms, min wall ms, [median process CPU ms] (both cores count); on a shared
machine the min is the best estimate of the uncontended cost.
Columns: pyramid (both images), extract (left then right, one thread), pair (extract_pair: right image
in the worker of orb.worker, `--worker`), stereo (match_stereo), frame = pyramid + pair + stereo.
Then the stages of one `extract` of the left image (`timing_ms`): median and min wall ms.
"""

from __future__ import annotations

import argparse
import os
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
        source = "KITTI 06 #0"
    else:
        rng = np.random.default_rng(0)
        tex = cv2.GaussianBlur(rng.normal(0, 1, (370, 1290)).astype(np.float32), (0, 0), 2.0)
        tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
        left, right = tex[:, 40:1266], tex[:, 30:1256]
        source = "synthetic"
    fx, baseline = 707.09, 0.537
    h, w = left.shape
    kitti_cam = StereoCamera(fx, fx, w / 2, h / 2, baseline, w, h)
    return [(f"{source} {w}x{h}", left, right, kitti_cam), _vga_pair(left, right, fx, baseline)]


def _vga_pair(left: np.ndarray, right: np.ndarray, fx: float, baseline: float):
    """A rendered frame of the simulated static street at 640x480 when the simulator is available, else
    the KITTI pair resized to 640x480 (rows stay rows, so it stays rectified)."""
    try:
        os.environ.setdefault("MUJOCO_GL", "egl")
        from sim.render import StereoRenderer
        from sim.scenarios import load_scenario
        from sim.world import build_world, camera_intrinsics

        cfg = load_scenario("static", ["frames=1", "image_size=640x480"])
        world = build_world(cfg)
        world.set_time(0.0)
        intrinsics = camera_intrinsics(cfg)
        with StereoRenderer(world, 640, 480) as renderer:
            frame = renderer.render(world.ego_T_m_c(0.0), intrinsics)
        camera = StereoCamera(*intrinsics, cfg.baseline, 640, 480)
        return "sim static 640x480", cv2.cvtColor(frame.left, cv2.COLOR_RGB2GRAY), cv2.cvtColor(frame.right, cv2.COLOR_RGB2GRAY), camera
    except ImportError:
        h, w = left.shape
        camera = StereoCamera(fx * 640 / w, fx * 480 / h, 320.0, 240.0, baseline, 640, 480)
        resize = lambda img: cv2.resize(img, (640, 480), interpolation=cv2.INTER_AREA)  # noqa: E731
        return "KITTI resized 640x480", resize(left), resize(right), camera


def _median_ms(fn, repeat: int) -> tuple[float, float, float]:
    """(median wall, min wall, median process CPU) in ms."""
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return float(np.median(wall)), float(np.min(wall)), float(np.median(cpu))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--n-features", type=int, default=2000)
    parser.add_argument("--right-factor", type=float, default=1.0, help="right-image budget / n_features")
    parser.add_argument("--cv-threads", type=int, default=None, help="cv2.setNumThreads (default: OpenCV's)")
    parser.add_argument("--worker", choices=["process", "thread"], default="process", help="orb.worker of extract_pair")
    parser.add_argument("--sad-half-height", type=int, default=None,
                        help="stereo SAD window half-height (default: the config's; 5 = ORB-SLAM2's 11x11)")
    args = parser.parse_args()
    if args.cv_threads is not None:
        cv2.setNumThreads(args.cv_threads)
    extractor = ORBExtractor(ORBConfig(n_features=args.n_features, worker=args.worker))
    extractor.start_worker(wait=True)
    n_right = int(round(args.n_features * args.right_factor))
    stereo_cfg = StereoConfig() if args.sad_half_height is None else StereoConfig(sad_half_height=args.sad_half_height)
    print(f"cv2 threads={cv2.getNumThreads()}, n_features={args.n_features}, right={n_right}, worker={args.worker}; "
          "ms: median wall, min wall [median cpu of this process]")
    header = ("image", "pyramid", "extract", "pair", "stereo", "frame")
    print(f"{header[0]:>22} " + " ".join(f"{h:>20}" for h in header[1:]) + "   n_kp  depth%")
    stages = []
    for name, left, right, camera in _pairs():
        pyr_l, pyr_r = extractor.build_pyramid(left), extractor.build_pyramid(right)
        kp_l, kp_r = extractor.extract_pair(pyr_l, pyr_r, n_features_right=n_right)

        def stereo():
            return match_stereo(kp_l, kp_r, pyr_l, pyr_r, camera, extractor.scale_factors, stereo_cfg)

        t_pyr = _median_ms(lambda: (extractor.build_pyramid(left), extractor.build_pyramid(right)), args.repeat)
        t_ext = _median_ms(lambda: (extractor.extract(pyr_l), extractor.extract(pyr_r, n_features=n_right)), args.repeat)
        t_pair = _median_ms(lambda: extractor.extract_pair(pyr_l, pyr_r, n_features_right=n_right), args.repeat)
        t_st = _median_ms(stereo, args.repeat)
        t_frame = tuple(a + b + c for a, b, c in zip(t_pyr, t_pair, t_st))
        _, depth = stereo()
        cells = " ".join(f"{w:6.1f} {m:5.1f} [{c:5.1f}]" for w, m, c in (t_pyr, t_ext, t_pair, t_st, t_frame))
        print(f"{name:>22} {cells} {len(kp_l):6d} {100 * np.mean(depth > 0):6.1f}%")
        stages.append((name, _stage_ms(extractor, pyr_l, args.repeat)))
    for name, ms in stages:
        print(f"{name:>22} stages of extract (left), median/min ms: " + ", ".join(f"{k} {m:.1f}/{n:.1f}" for k, (m, n) in ms.items()))


def _stage_ms(extractor: ORBExtractor, pyramid: list[np.ndarray], repeat: int) -> dict[str, tuple[float, float]]:
    """Per stage of `extract`: (median, min) wall ms over `repeat` runs."""
    runs = []
    for _ in range(repeat):
        timing: dict[str, float] = {}
        extractor.extract(pyramid, timing_ms=timing)
        runs.append(timing)
    return {k: (float(np.median([r[k] for r in runs])), float(np.min([r[k] for r in runs]))) for k in runs[0]}


if __name__ == "__main__":
    main()
