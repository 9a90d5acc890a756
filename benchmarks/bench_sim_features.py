"""ORB keypoints on vehicles, the simulator against real KITTI: are the sim's vehicles as easy (or as
hard) for the feature extractor as real cars?

    python benchmarks/bench_sim_features.py [--kitti ../shared/data/kitti-odometry-06]
        [--scenarios traffic following crossing static] [--seeds 0] [--work /tmp/bench_dynamic]

For every vehicle box it counts the keypoints of the project's ORB extractor (the default config)
in the box and in the box's inner part (15 % of its width and height off each side: the keypoints
away from the silhouette, which slide with the background), per 1000 px^2 of box. Real boxes: the
parked and driving cars of the KITTI odometry 06 clip in `KITTI_06_CARS`, marked by hand on the left
images (the clip has no object labels). Sim boxes: the ground-truth 2D boxes of cars, vans and trucks
entirely inside the image, every 10th frame of the bench_dynamic sequences (generated into --work if
absent). KITTI is extracted twice: with the default 2000 features on its 1226x370 images, and with
the sim's budget per pixel (the default over SIM_SIZE), which is the fair comparison. Prints the median
densities per source and box-area bin.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from bench_dynamic import ensure_sequence
from dynaslam2.config import load_config
from dynaslam2.features.orb import ORBExtractor
from dynaslam2.io.sequence import open_sequence

# (left image, left, top, right, bottom) in px: the cars of kitti-odometry-06 frames 0-40 that are
# unoccluded and >= 25 px high, marked by hand.
KITTI_06_CARS = [
    ("000000", 712, 168, 842, 255),
    ("000000", 645, 172, 688, 200),
    ("000010", 662, 172, 726, 215),
    ("000010", 160, 194, 231, 225),
    ("000020", 722, 181, 858, 264),
    ("000040", 84, 184, 172, 228),
]
SIM_SIZE = (640, 480)  # the bench_dynamic sequences' image size (width, height)
AREA_BINS = [(400, 1500), (1500, 4000), (4000, 15000), (15000, np.inf)]  # px^2; smaller boxes are left out
INNER_MARGIN = 0.15  # fraction of the box's width / height off each side for the inner part


def box_counts(uv: np.ndarray, box) -> tuple[float, int, int]:
    """(area px^2, keypoints in the box, keypoints in its inner part)."""
    x0, y0, x1, y1 = (float(b) for b in box)
    w, h = x1 - x0, y1 - y0
    inside = (uv[:, 0] >= x0) & (uv[:, 0] < x1) & (uv[:, 1] >= y0) & (uv[:, 1] < y1)
    mx, my = INNER_MARGIN * w, INNER_MARGIN * h
    inner = (uv[:, 0] >= x0 + mx) & (uv[:, 0] < x1 - mx) & (uv[:, 1] >= y0 + my) & (uv[:, 1] < y1 - my)
    return w * h, int(inside.sum()), int(inner.sum())


def kitti_images(kitti: Path) -> dict[str, np.ndarray]:
    """The grayscale left images of KITTI_06_CARS by name."""
    images = {}
    for name in sorted({car[0] for car in KITTI_06_CARS}):
        path = kitti / "image_0" / f"{name}.png"
        images[name] = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if images[name] is None:
            raise SystemExit(f"--kitti: cannot read {path} (expected the kitti-odometry-06 clip)")
    return images


def kitti_rows(images: dict[str, np.ndarray], n_features: int) -> list[tuple[float, int, int]]:
    ext = ORBExtractor(load_config(None, [f"orb.n_features={n_features}", "orb.threads=1"]).orb)
    uv = {name: ext.extract(ext.build_pyramid(gray)).uv for name, gray in images.items()}
    return [box_counts(uv[name], box) for name, *box in KITTI_06_CARS]


def sim_rows(work: Path, scenarios: list[str], seeds: list[int]) -> list[tuple[float, int, int]]:
    ext = ORBExtractor(load_config(None, ["orb.threads=1"]).orb)
    rows = []
    for scenario in scenarios:
        for seed in seeds:
            seq = open_sequence(ensure_sequence(work, scenario, seed, 150, "{}x{}".format(*SIM_SIZE)))
            w, h = seq.camera.width, seq.camera.height
            for i in range(0, len(seq), 10):
                boxes = [g.box2d for g in seq.gt_objects(i) if g.cls in ("car", "van", "truck") and g.box2d is not None
                         and g.box2d[0] > 1 and g.box2d[1] > 1 and g.box2d[2] < w - 2 and g.box2d[3] < h - 2]
                if boxes:
                    uv = ext.extract(ext.build_pyramid(seq[i].left)).uv
                    rows.extend(box_counts(uv, b) for b in boxes)
    return rows


def report(label: str, rows: list[tuple[float, int, int]]) -> None:
    r = np.array(rows, dtype=float).reshape(-1, 3)
    r = r[r[:, 0] >= AREA_BINS[0][0]]
    for lo, hi in AREA_BINS:
        s = r[(r[:, 0] >= lo) & (r[:, 0] < hi)]
        if len(s):
            print(f"{label:30s} {lo:>6.0f}-{hi:<6.0f} {len(s):5d} {np.median(s[:, 1]):8.0f} "
                  f"{np.median(1e3 * s[:, 1] / s[:, 0]):10.1f} {np.median(1e3 * s[:, 2] / s[:, 0]):10.1f}")
    print(f"{label:30s} {'all':13s} {len(r):5d} {np.median(r[:, 1]):8.0f} {np.median(1e3 * r[:, 1] / r[:, 0]):10.1f} "
          f"{np.median(1e3 * r[:, 2] / r[:, 0]):10.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kitti", type=Path, default=Path(__file__).resolve().parents[2] / "shared/data/kitti-odometry-06")
    ap.add_argument("--scenarios", nargs="+", default=["traffic", "following", "crossing", "static"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_dynamic"))
    args = ap.parse_args()
    if not (args.kitti / "image_0").is_dir():
        raise SystemExit(f"--kitti: {args.kitti} has no image_0/ (expected the kitti-odometry-06 clip)")
    images = kitti_images(args.kitti)
    n_sim = load_config(None, []).orb.n_features
    fair = int(round(n_sim * next(iter(images.values())).size / (SIM_SIZE[0] * SIM_SIZE[1])))
    print(f"{'source':30s} {'box px^2':13s} {'boxes':>5s} {'kp/box':>8s} {'kp/1000px':>10s} {'inner/1000':>10s}")
    report(f"KITTI 06, {n_sim} features", kitti_rows(images, n_sim))
    report(f"KITTI 06, {fair} features", kitti_rows(images, fair))
    report(f"sim, {n_sim} features", sim_rows(args.work, args.scenarios, args.seeds))


if __name__ == "__main__":
    main()
