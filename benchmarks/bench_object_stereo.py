"""Stereo accuracy of the object keypoints on simulated sequences, against the rendered depth.

Each keypoint that `dynamic` mode's frame builder puts on a dynamic-class instance and gives a depth (stereo
matching, then the row search) is compared with the disparity bf / z of the rendered depth at its pixel, within
`objects.max_point_depth_m`. The figures are split by whether the keypoint's SAD window (stereo.sad_window x
stereo.sad_half_height, on the keypoint's pyramid level) holds pixels of another instance label (an outline: its
window reaches over the object's silhouette) or lies on the keypoint's own instance (inside), and by pyramid
level: median absolute error (level-0 px), the share over 0.5 and 1 px, and the keypoints without a depth.

    python benchmarks/bench_object_stereo.py [--scenario crossing] [--seeds 100] [--frames 150] [--size 640x480]
        [--every 5] [--work DIR] [--set k=v ...] [--sim-set k=v ...]

Sequences are generated into --work as by bench_dynamic.py (the sim's world version is part of the folder name).
Why it exists: on world 3's aliased images, outline keypoints were 0.21 px off (median) against 0.06 px inside,
and the rendered depth in place of their stereo lowered `crossing` 100-114's object ATE 0.301 -> 0.227 m; world 4
renders anti-aliased colour passes (`sim.render.RenderConfig.msaa_samples`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from dynaslam2.config import load_config
from dynaslam2.errors import InputError
from dynaslam2.features.orb import base_to_level, level_scales, to_gray
from dynaslam2.features.stereo import labels_at_level
from dynaslam2.io.sequence import open_sequence
from dynaslam2.tracking.frontend import FrameBuilder
from sim.scenarios import load_scenario

from bench_dynamic import ensure_sequence  # this script's folder (python benchmarks/bench_object_stereo.py)


def window_on_other_label(uv: np.ndarray, octave: np.ndarray, pyr_shapes: list[tuple[int, int]],
                          scales: np.ndarray, labels: np.ndarray, w: int, h: int) -> np.ndarray:
    """(N,) whether each keypoint's (2w+1) x (2h+1) window on its level holds a label other than its own pixel's
    (`labels`: HxW level 0, sampled on each level by `labels_at_level`; `scales`: `level_scales`)."""
    H, W = labels.shape
    own = labels[np.clip(np.rint(uv[:, 1]).astype(int), 0, H - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, W - 1)]
    other = np.zeros(len(uv), bool)
    for level in np.unique(octave).tolist():
        sel = np.flatnonzero(octave == level)
        hl, wl = pyr_shapes[level]
        lab = np.pad(labels_at_level(labels, pyr_shapes[level], scales[level]), ((h, h), (w, w)), mode="edge")
        su = np.clip(np.rint(base_to_level(uv[sel, 0], scales[level, 0])).astype(int), 0, wl - 1)
        sv = np.clip(np.rint(base_to_level(uv[sel, 1], scales[level, 1])).astype(int), 0, hl - 1)
        win = np.lib.stride_tricks.sliding_window_view(lab, (2 * h + 1, 2 * w + 1))[sv, su]
        other[sel] = np.any(win != own[sel, None, None], axis=(1, 2))
    return other


def frame_errors(builder: FrameBuilder, data, camera, pyr_shapes: list[tuple[int, int]], scales: np.ndarray,
                 max_depth_m: float) -> dict[str, np.ndarray]:
    """Per object keypoint of one frame: octave, outline flag, disparity error (px; nan without a depth)."""
    frame = builder.build(data, {})
    kp = frame.keypoints
    on_objects = ~frame.static
    col = np.clip(np.rint(kp.uv[:, 0]).astype(int), 0, camera.width - 1)
    row = np.clip(np.rint(kp.uv[:, 1]).astype(int), 0, camera.height - 1)
    z_gt = data.depth[row, col].astype(np.float64)
    use = on_objects & np.isfinite(z_gt) & (z_gt > 0) & (z_gt <= max_depth_m)
    uv, octave = kp.uv[use].astype(np.float64), kp.octave[use]
    stereo = builder.config.stereo
    outline = window_on_other_label(uv, octave, pyr_shapes, scales, data.instances, stereo.sad_window,
                                    stereo.sad_half_height)
    z = frame.depth[use]
    error = np.where(z > 0, camera.bf / np.where(z > 0, z, 1.0) - camera.bf / z_gt[use], np.nan)
    return {"octave": octave, "outline": outline, "error": error}


def summary(error: np.ndarray) -> str:
    found = np.abs(error[np.isfinite(error)])
    if len(found) == 0:
        return f"{len(error):6d} keypoints, none with a depth"
    return (f"{len(error):6d} keypoints, {100 * (1 - len(found) / len(error)):4.1f} % without depth, median "
            f"{np.median(found):.3f} px, > 0.5 px {100 * np.mean(found > 0.5):4.1f} %, > 1 px {100 * np.mean(found > 1):4.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="crossing")
    ap.add_argument("--seeds", nargs="+", type=int, default=[100])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--every", type=int, default=5, help="use every n-th frame")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_dynamic"))
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--sim-set", dest="sim_overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    if args.every < 1:
        ap.error(f"--every: expected a positive integer, got {args.every}")
    try:
        config = load_config(None, args.overrides + ["mode=dynamic"])
        load_scenario(args.scenario, [f"frames={args.frames}", f"image_size={args.size}", *args.sim_overrides])
    except InputError as e:
        ap.error(str(e))
    args.work.mkdir(parents=True, exist_ok=True)
    parts = []
    for seed in args.seeds:
        path = ensure_sequence(args.work, args.scenario, seed, args.frames, args.size, tuple(args.sim_overrides))
        seq = open_sequence(path)
        builder = FrameBuilder(config, seq.camera)
        pyr_shapes = scales = None
        for i in range(0, len(seq), args.every):
            data = seq[i]
            if data.depth is None or data.instances is None or data.right is None:
                raise SystemExit(f"{path}: frame {i} lacks a right image, a depth image or instances")
            if pyr_shapes is None:
                pyramid = builder.extractor.build_pyramid(to_gray(data.left))
                pyr_shapes, scales = [p.shape[:2] for p in pyramid], level_scales(pyramid)
            parts.append(frame_errors(builder, data, seq.camera, pyr_shapes, scales,
                                      config.objects.max_point_depth_m))
    octave = np.concatenate([p["octave"] for p in parts])
    outline = np.concatenate([p["outline"] for p in parts])
    error = np.concatenate([p["error"] for p in parts])
    print(f"object keypoints' disparity error against the rendered depth: {args.scenario} seeds {args.seeds}, "
          f"every {args.every} frames, {args.size}")
    for name, sel in (("inside ", ~outline), ("outline", outline)):
        print(f"  {name}           {summary(error[sel])}")
        for level in np.unique(octave[sel]).tolist():
            print(f"  {name} level {level}   {summary(error[sel & (octave == level)])}")


if __name__ == "__main__":
    main()
