"""Benchmark of the bundle adjustment with objects (dynaslam2.optim.object_ba), median ms.

    python benchmarks/bench_object_ba.py [--repeats 5] [--set optim.objects.motion_points_variable=true ...]
    python benchmarks/bench_object_ba.py --capture /tmp/bench_dynamic/traffic_s0_150_640x480_w2 --windows W.pkl
    python benchmarks/bench_object_ba.py --windows W.pkl --compare optim.objects.motion_form=stacked ""

--capture runs the `dynamic` mode on a sequence and saves every BA-with-objects window it solves
(the problems as built by mapping.objects.object_local_ba); --compare replays them under two
comma-separated override lists A and B, alternating in the same run (best of 2 per window), and
prints per-window CPU times, iterations and final costs, and the median B/A ratio.

A traffic-like synthetic window (dynaslam2.optim.synthetic_objects): 10 keyframes over 2 s (2 fixed),
a KITTI-like stereo camera at 8 m/s, 1500 static points seen by up to 5 keyframes, 4 objects x 80
points moving at constant velocity, each seen in every keyframe. Times the three cases of paper III-D
(camera weak only = static local BA, object weak only, both), the "direct" eq. (2) parametrization
against the default Q = T_o_c one, eq. (4) in 3 rows per point ("stacked") against the 12-row
"moments" form, eq. (4) with the object points as variables, and the joint BA from
a mild initialization (as after tracking) next to the static one. Wall and CPU
(process) time are printed: the machine is shared, CPU time is the steadier figure.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pickle
import time
from pathlib import Path

import numpy as np

from dynaslam2.config import load_config
from dynaslam2.geometry.se3 import inverse, se3_log
from dynaslam2.optim.object_ba import object_bundle_adjustment
from dynaslam2.optim.synthetic import kitti_like_camera
from dynaslam2.optim.synthetic_objects import make_object_window

CAMERA = kitti_like_camera()


def errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position error of the frame origins (m) and rotation error (deg)."""
    d = se3_log(T_est @ inverse(T_true))
    position = np.linalg.norm(T_est[..., :3, 3] - T_true[..., :3, 3], axis=-1)
    return position, np.degrees(np.linalg.norm(d[..., 3:], axis=-1))


def run(label: str, window, problem, cfg, repeats: int) -> float:
    wall, cpu, results = [], [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        results.append(object_bundle_adjustment(problem, CAMERA, cfg))
        wall.append(1e3 * (time.perf_counter() - t))
        cpu.append(1e3 * (time.process_time() - c))
    r = results[-1]
    free = ~problem.fixed
    cam_t, _ = errors(r.T_c_w[free], window.T_c_w_true[free])
    obj_t, obj_r = errors(r.T_w_o, window.T_w_o_true)
    print(f"{label}: median {np.median(wall):.0f} ms wall, {np.median(cpu):.0f} ms CPU (build "
          f"{np.median([x.timings_ms['build'] for x in results]):.0f}, LM "
          f"{np.median([x.timings_ms['solve'] for x in results]):.0f} ms wall), {r.iterations} LM iterations; "
          f"camera median {100 * np.median(cam_t):.2f} cm; object median {100 * np.median(obj_t):.2f} cm "
          f"{np.median(obj_r):.3f} deg")
    return float(np.median(cpu))


def capture(sequence: Path, out: Path, overrides: list[str]) -> None:
    """Run the dynamic mode on `sequence` (config `overrides`), pickling every (problem, camera) passed to the
    object BA."""
    import dynaslam2.mapping.objects as mapping_objects
    from dynaslam2.io.sequence import open_sequence
    from dynaslam2.system import System

    windows = []

    def recording(problem, camera, cfg):
        windows.append((problem, camera))
        return object_bundle_adjustment(problem, camera, cfg)

    mapping_objects.object_bundle_adjustment = recording  # the benchmark's own process only
    seq = open_sequence(sequence)
    system = System(load_config(None, ["mode=dynamic"] + overrides), seq.camera)
    for i in range(len(seq)):
        system.process(seq[i])
    tmp = out.with_suffix(".tmp")
    with open(tmp, "wb") as fh:
        pickle.dump(windows, fh)
    os.replace(tmp, out)
    print(f"{len(windows)} windows -> {out}")


def compare(windows_path: Path, spec_a: str, spec_b: str, base: list[str]) -> None:
    """Replay saved windows under override lists A and B (same run, alternating), CPU time per window."""
    with open(windows_path, "rb") as fh:
        windows = pickle.load(fh)
    cfgs = [load_config(None, base + [kv for kv in spec.split(",") if kv]).optim for spec in (spec_a, spec_b)]
    rows = []
    for i, (problem, camera) in enumerate(windows):
        out = []
        for cfg in cfgs:
            best = np.inf
            for _ in range(2):
                c = time.process_time()
                result = object_bundle_adjustment(problem, camera, cfg)
                best = min(best, 1e3 * (time.process_time() - c))
            out.append((best, result))
        (ta, ra), (tb, rb) = out
        rows.append((ta, tb, ra.final_error, rb.final_error))
        case = "both" if problem.optimize_static else "object weak"
        print(f"{i:3d} {case:11s} K={len(problem.T_c_w)} static obs {len(problem.obs_kf)} object obs "
              f"{len(problem.oobs_f)}: A {ta:.0f} ms ({ra.iterations} it, cost {ra.final_error:.2f}), "
              f"B {tb:.0f} ms ({rb.iterations} it, cost {rb.final_error:.2f}), B/A {tb / ta:.2f}", flush=True)
    a = np.array(rows)
    print(f"A: {spec_a or 'defaults'}; B: {spec_b or 'defaults'}; {len(a)} windows, load average "
          f"{os.getloadavg()[0]:.2f}: median CPU A {np.median(a[:, 0]):.0f} ms, B {np.median(a[:, 1]):.0f} ms; "
          f"median B/A {np.median(a[:, 1] / a[:, 0]):.3f}, summed B/A {a[:, 1].sum() / a[:, 0].sum():.3f}; "
          f"summed final cost A {a[:, 2].sum():.1f}, B {a[:, 3].sum():.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="config override key=value (optim.* for the replays; any key for --capture)")
    parser.add_argument("--capture", type=Path, metavar="SEQ", help="save the object BA windows of a dynamic run")
    parser.add_argument("--windows", type=Path, help="file of saved windows (written by --capture)")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"), help="replay --windows under two override lists")
    args = parser.parse_args()
    if args.capture or args.compare:
        if args.windows is None:
            parser.error("--capture and --compare need --windows")
        if args.capture:
            capture(args.capture, args.windows, args.overrides)
        if args.compare:
            compare(args.windows, *args.compare, args.overrides)
        return
    cfg = load_config(None, args.overrides).optim
    window = make_object_window(np.random.default_rng(0), CAMERA, n_keyframes=10, n_fixed=2, n_static=1500,
                                n_objects=4, n_object_points=80, outlier_fraction=0.05)
    p = window.problem
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; K={len(p.T_c_w)} static points "
          f"{len(p.X_w)} ({len(p.obs_kf)} obs), object observations {len(p.obj_frames)}, object points "
          f"{len(p.X_o)} ({len(p.oobs_f)} obs)")
    run("camera weak only (static local BA)", window, dataclasses.replace(p, optimize_objects=False), cfg,
        args.repeats)
    run("object weak only (static points fixed)", window, dataclasses.replace(p, optimize_static=False), cfg,
        args.repeats)
    both = run("both (joint, Q = T_o_c)", window, p, cfg, args.repeats)
    direct_cfg = dataclasses.replace(cfg, objects=dataclasses.replace(cfg.objects, parametrization="direct"))
    direct = run("both (joint, direct eq. 2 factors)", window, p, direct_cfg, args.repeats)
    print(f"direct / Q CPU time ratio: {direct / both:.1f}")
    stacked_cfg = dataclasses.replace(cfg, objects=dataclasses.replace(cfg.objects, motion_form="stacked"))
    stacked = run("both (joint, eq. 4 stacked: 3 rows per point)", window, p, stacked_cfg, args.repeats)
    print(f"eq. 4 moments / stacked CPU time ratio: {both / stacked:.2f}")
    points_cfg = dataclasses.replace(cfg, objects=dataclasses.replace(cfg.objects, motion_points_variable=True))
    run("both (joint, eq. 4 with object points as variables)", window, p, points_cfg, args.repeats)
    # initial errors as after tracking (1 cm / 0.06 deg cameras, 2 cm / 0.3 deg objects, 0.2 m/s, 2 cm points)
    mild = make_object_window(np.random.default_rng(0), CAMERA, n_keyframes=10, n_fixed=2, n_static=1500,
                              n_objects=4, n_object_points=80, outlier_fraction=0.05, camera_sigma=(0.01, 0.001),
                              object_sigma=(0.02, 0.005), velocity_sigma=(0.2, 0.02), point_sigma=0.02)
    run("camera weak only, mild init", mild, dataclasses.replace(mild.problem, optimize_objects=False), cfg,
        args.repeats)
    run("both (joint, Q = T_o_c), mild init", mild, mild.problem, cfg, args.repeats)


if __name__ == "__main__":
    main()
