"""Benchmark of dynaslam2.optim: pose-only optimization and local bundle adjustment (median ms).

    python benchmarks/bench_ba.py [--repeats 7] [--set optim.ordering=COLAMD ...] [--pose-builtin]
        [--compare optim.lambda_fixed_factor=true,optim.linear_solver=SEQUENTIAL_CHOLESKY ...]
        [--slam-windows SEQ [--slam-frames 51]]

Synthetic KITTI-like problems (dynaslam2.optim.synthetic): pose-only with N = 300 and 1000
correspondences (half stereo, 20% gross outliers); local BA on 10 local + 5 fixed keyframes
1 m apart, 3000 points seen by up to 7 consecutive keyframes (~14k observations, 5% outliers),
from a hard (5 cm) and a mild (1 cm, as after tracking) initialization, and 1000 points.
Wall and CPU (process) time are both printed: the machine is shared, CPU time is the steadier figure.
`--compare` adds a config variant (comma-separated overrides on top of --set): the BA windows then run
every variant in turn within each repeat and print its median CPU time as a ratio to the first config.
`--pose-builtin` also times the pose-only alternative built from gtsam built-in factors only
(points as variables held by strong priors), to compare with the CustomFactor used.
`--slam-windows SEQ` instead replays the local BA windows of a SLAM run (static mode, the first
`--slam-frames` frames of SEQ, e.g. ../shared/data/kitti-odometry-06): every config on every window,
CPU time as a ratio to the first config, and how far each ends from the converged window (30 + 60
LM iterations, no early stop): mean keyframe distance and cost ratio. Real windows start near their
optimum (only the new keyframe and points are off), unlike the synthetic ones.
"""

from __future__ import annotations

import argparse
import copy
import os
import time
from pathlib import Path

import gtsam
import numpy as np

import dynaslam2.mapping.local_mapping as local_mapping
from dynaslam2.config import OptimConfig, load_config
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse, se3_exp, transform
from dynaslam2.io.sequence import open_sequence
from dynaslam2.optim import BAProblem, local_bundle_adjustment, optimize_pose
from dynaslam2.optim.gtsam_utils import (
    StereoFactorCache,
    add_stereo_projection_factors,
    allocate_keys,
    insert_points,
    lm_params,
    matrix_from_pose3,
    pose3_from_matrix,
)
from dynaslam2.optim.reprojection import chi2, chi2_thresholds, residuals
from dynaslam2.optim.synthetic import kitti_like_camera, make_window, observe, perturb_poses, sample_points_in_view
from dynaslam2.system import System

CAMERA = kitti_like_camera()


def pose_problem(rng: np.random.Generator, n: int):
    T_c_w = inverse(se3_exp(np.array([0.3, -0.1, 2.0, 0.01, 0.05, -0.02])))
    X_w = sample_points_in_view(rng, CAMERA, T_c_w, n, (3.0, 40.0))
    obs = observe(rng, CAMERA, transform(T_c_w, X_w), rng.random(n) < 0.5, 0.2)
    return perturb_poses(rng, T_c_w, 0.1, 0.02), X_w, obs


def optimize_pose_builtin(T_c_w_init, X_w, meas, inv_sigma2, cfg: OptimConfig) -> np.ndarray:
    """The same rounds with built-in factors only: points as Point3 variables held by strong priors."""
    th = chi2_thresholds(meas, cfg.chi2_mono, cfg.chi2_stereo)
    inliers = np.ones(len(X_w), dtype=bool)
    T_c_w = T_c_w_init
    for rnd in range(cfg.pose_rounds):
        idx = np.flatnonzero(inliers)
        (pose_key,), point_keys = allocate_keys(1, len(idx))
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        values.insert(int(pose_key), pose3_from_matrix(inverse(T_c_w_init)))
        insert_points(values, point_keys, X_w[idx])
        prior = gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)
        for key, X in zip(point_keys.tolist(), X_w[idx]):
            graph.addPriorPoint3(key, X, prior)
        robust = rnd < cfg.pose_robust_rounds
        add_stereo_projection_factors(graph, np.zeros(len(idx), np.int64), point_keys, meas[idx], inv_sigma2[idx],
                                      CAMERA, np.sqrt(cfg.chi2_mono) if robust else None,
                                      np.sqrt(cfg.chi2_stereo) if robust else None)
        ordering = np.concatenate([point_keys, [pose_key]])
        params = lm_params(cfg, cfg.pose_iterations, cfg.pose_relative_error_tol, ordering)
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        T_c_w = inverse(matrix_from_pose3(result.atPose3(int(pose_key))))
        X_c = transform(T_c_w, X_w)
        inliers = (chi2(residuals(CAMERA, X_c, meas), inv_sigma2) <= th) & (X_c[:, 2] > cfg.min_depth)
    return T_c_w


def median_ms(fn, repeats: int) -> tuple[float, float, list]:
    """Median wall and CPU (process) milliseconds of `fn()` over `repeats` calls, and its outputs."""
    wall, cpu, outputs = [], [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        outputs.append(fn())
        wall.append(1e3 * (time.perf_counter() - t))
        cpu.append(1e3 * (time.process_time() - c))
    return float(np.median(wall)), float(np.median(cpu)), outputs


def bench_window(rng: np.random.Generator, cfgs: list[tuple[str, OptimConfig]], repeats: int, n_points: int,
                 mild: bool) -> None:
    """Local BA on 10 local + 5 fixed keyframes; `mild`: 1 cm / 0.06 deg / 2 cm initial errors (a window
    after tracking), else 5 cm / 0.3 deg / 5 cm. The configs run in turn within each repeat."""
    sigmas = dict(pose_sigma=(0.01, 0.001), point_sigma=0.02)
    if not mild:
        sigmas = dict(pose_sigma=(0.05, 0.005), point_sigma=0.05)
    window = make_window(rng, CAMERA, n_keyframes=15, n_fixed=5, n_points=n_points, track_length=7,
                         outlier_fraction=0.05, **sigmas)
    problem = BAProblem(window.T_c_w_init, window.fixed, window.X_w_init, window.obs_kf, window.obs_pt,
                        window.obs.meas, window.obs.inv_sigma2)
    runs = [[] for _ in cfgs]
    for _ in range(repeats):
        for i, (_, cfg) in enumerate(cfgs):
            runs[i].append(median_ms(lambda: local_bundle_adjustment(problem, CAMERA, cfg), 1))
    cpu_first = np.median([run[1] for run in runs[0]])
    free = ~window.fixed
    for (name, _), run in zip(cfgs, runs):
        wall, cpu = np.median([x[0] for x in run]), np.median([x[1] for x in run])
        results = [x[2][0] for x in run]
        build = np.median([r.timings_ms["build"] for r in results])
        solve = np.median([r.timings_ms["solve"] for r in results])
        r = results[-1]
        t_err = np.linalg.norm((r.T_c_w[free] @ inverse(window.T_c_w_true[free]))[:, :3, 3], axis=1).max()
        print(f"local BA ({'mild' if mild else 'hard'} init) K={len(problem.T_c_w)} ({int(problem.fixed.sum())} "
              f"fixed) P={len(problem.X_w)} M={len(problem.obs_kf)} [{name}]: median {wall:.0f} ms wall, {cpu:.0f} "
              f"ms CPU ({cpu / cpu_first:.2f}x) (build {build:.0f} ms, LM {solve:.0f} ms, numpy rest "
              f"{wall - build - solve:.0f} ms wall), {r.iterations} LM iterations, Huber cost {r.initial_error:.0f} "
              f"-> {r.final_error:.0f}, inliers {r.inlier.mean():.3f}, max keyframe error {100 * t_err:.2f} cm")


def slam_windows(seq_path: Path, frames: int) -> tuple[list[BAProblem], StereoCamera]:
    """The local BA windows of a static-mode SLAM run on the first `frames` frames, in order, and the
    camera (captured by wrapping the local BA that local mapping calls)."""
    seq = open_sequence(seq_path)
    windows = []
    solve = local_mapping.local_bundle_adjustment

    def capture(problem, camera, cfg, cache=None):
        windows.append(problem)
        return solve(problem, camera, cfg, cache)

    local_mapping.local_bundle_adjustment = capture
    try:
        system = System(load_config(None, ["mode=static"]), seq.camera)
        for i in range(min(frames, len(seq))):
            system.process(seq[i])
    finally:
        local_mapping.local_bundle_adjustment = solve
    return windows, seq.camera


def bench_slam_windows(seq_path: Path, frames: int, cfgs: list[tuple[str, OptimConfig]], repeats: int) -> None:
    """Every config on every captured window (min CPU of `repeats`), against the converged window."""
    windows, camera = slam_windows(seq_path, frames)
    converge = OptimConfig(local_ba_iterations_robust=30, local_ba_iterations_refine=60, ba_relative_error_tol=0.0)
    cpu = np.zeros((len(cfgs), len(windows)))
    dist_cm = np.zeros_like(cpu)
    cost_ratio = np.zeros_like(cpu)
    caches = [StereoFactorCache() for _ in cfgs]  # per config, windows in SLAM order (as local mapping)
    for j, problem in enumerate(windows):
        ref = local_bundle_adjustment(problem, camera, converge)
        free = ~problem.fixed
        for i, (_, cfg) in enumerate(cfgs):
            runs = []
            for _ in range(repeats):  # each repeat from the cache state after window j - 1
                cache = copy.copy(caches[i])
                runs.append(median_ms(lambda: local_bundle_adjustment(problem, camera, cfg, cache), 1))
            caches[i] = cache
            cpu[i, j] = min(r[1] for r in runs)
            r = runs[-1][2][0]
            dist_cm[i, j] = 100 * np.linalg.norm(r.T_c_w[free, :3, 3] - ref.T_c_w[free, :3, 3], axis=1).mean()
            cost_ratio[i, j] = r.final_error / ref.final_error
    sizes = np.array([(len(w.X_w), len(w.obs_kf)) for w in windows])
    print(f"{len(windows)} local BA windows of {seq_path.name} (median {np.median(sizes[:, 0]):.0f} points, "
          f"{np.median(sizes[:, 1]):.0f} observations)")
    for i, (name, _) in enumerate(cfgs):
        print(f"  [{name}] median {np.median(cpu[i]):.0f} ms CPU ({np.median(cpu[i] / cpu[0]):.2f}x per window, "
              f"{cpu[i].sum() / cpu[0].sum():.2f}x summed); from the converged window: keyframes "
              f"{np.median(dist_cm[i]):.2f} cm (median of means, max {dist_cm[i].max():.2f}), cost "
              f"x{np.median(cost_ratio[i]):.4f} (max x{cost_ratio[i].max():.4f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="config override optim.key=value")
    parser.add_argument("--pose-builtin", action="store_true", help="also time the built-in-factor pose-only variant")
    parser.add_argument("--skip-pose", action="store_true")
    parser.add_argument("--compare", action="append", default=[],
                        help="a config variant for the BA windows: comma-separated optim.key=value overrides")
    parser.add_argument("--slam-windows", type=Path, default=None, metavar="SEQ",
                        help="replay the local BA windows of a SLAM run on SEQ instead of the synthetic benchmarks")
    parser.add_argument("--slam-frames", type=int, default=51)
    args = parser.parse_args()
    cfg = load_config(None, args.overrides).optim
    cfgs = [("config", cfg)] + [(v, load_config(None, args.overrides + v.split(",")).optim) for v in args.compare]
    rng = np.random.default_rng(0)
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    if args.slam_windows is not None:
        bench_slam_windows(args.slam_windows, args.slam_frames, cfgs, args.repeats)
        return
    if not args.skip_pose:
        for n in (300, 1000):
            T_init, X_w, obs = pose_problem(rng, n)
            wall, cpu, _ = median_ms(lambda: optimize_pose(T_init, X_w, obs.meas, obs.inv_sigma2, CAMERA, cfg),
                                     args.repeats)
            print(f"pose-only N={n}: median {wall:.1f} ms wall, {cpu:.1f} ms CPU (CustomFactor, up to "
                  f"{cfg.pose_rounds} rounds x {cfg.pose_iterations} LM iterations)")
            if args.pose_builtin:
                wall, cpu, _ = median_ms(lambda: optimize_pose_builtin(T_init, X_w, obs.meas, obs.inv_sigma2, cfg),
                                         args.repeats)
                print(f"pose-only N={n}: median {wall:.1f} ms wall, {cpu:.1f} ms CPU (built-in factors, points held "
                      f"by priors)")
    for n_points, mild in ((3000, False), (3000, True), (1000, True)):
        bench_window(rng, cfgs, args.repeats, n_points, mild)

if __name__ == "__main__":
    main()
