"""End-to-end SLAM benchmark: per-stage median ms, local-mapping breakdown, fps and accuracy.

    python benchmarks/bench_slam.py [--seq DIR ...] [--sim SCENARIO] [--sim-frames N] [--mode static]
        [--frames N] [--set k=v ...] [--profile] [--clock {wall,cpu}]

Default: the real KITTI odometry 06 clip in ../shared/data (1226x370), then a simulated 640x480
sequence (`--sim` scenario, generated into a temporary folder; `--sim none` skips it). Stages are those of
timing.csv (features, stereo, tracking, objects, local_ba, boxes, total); `local_ba` is all of local
mapping, with its breakdown (process, triangulation, fusion, ba, kf_culling) medians over keyframes.
fps = frames / summed `total` (one process: tracking + local mapping + BA); cpu_fps = frames / process
CPU time of the loop (all threads): steadier than wall time on a shared machine, for A/B comparisons.
`--clock cpu` makes every stage timing process CPU time (time.perf_counter is replaced by
time.process_time for the run), so that per-stage A/B comparisons survive a loaded machine.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile
import time
from pathlib import Path

import numpy as np

from dynaslam2.config import load_config
from dynaslam2.eval.trajectory import ate, rpe
from dynaslam2.io.sequence import open_sequence
from dynaslam2.system import System

DEFAULT_SEQ = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti-odometry-06"


def bench(seq_path: Path, mode: str, frames: int | None, overrides: list[str], profile: bool) -> dict:
    seq = open_sequence(seq_path)
    n = len(seq) if frames is None else min(frames, len(seq))
    data = [seq[i] for i in range(n)]  # load images first: disk reads are not SLAM time
    system = System(load_config(None, overrides + [f"mode={mode}"]), seq.camera)
    prof = cProfile.Profile() if profile else None
    estimates = []
    t0, c0 = time.monotonic(), time.process_time()  # monotonic: wall time even with --clock cpu
    if prof:
        prof.enable()
    for frame in data:
        estimates.append(system.process(frame))
    if prof:
        prof.disable()
    wall, cpu = time.monotonic() - t0, time.process_time() - c0
    stages = {k: np.array([e.timing_ms[k] for e in estimates]) for k in estimates[0].timing_ms}
    kf = [e for e in estimates if e.mapping_ms]
    mapping = {k: float(np.median([e.mapping_ms[k] for e in kf])) for k in (kf[0].mapping_ms if kf else {})}
    T = np.array([e.T_w_c for e in estimates])
    out = {
        "sequence": str(seq_path), "size": f"{seq.camera.width}x{seq.camera.height}", "frames": n,
        "keyframes": len(kf), "lost": sum(e.state == "lost" for e in estimates),
        "median_ms": {k: float(np.median(v)) for k, v in stages.items()},
        "median_ms_keyframes": {"local_mapping": float(np.median([e.timing_ms["local_ba"] for e in kf])) if kf else 0.0,
                                **mapping},
        "fps": n / (stages["total"].sum() / 1e3), "wall_fps": n / wall, "cpu_fps": n / cpu,
    }
    if seq.gt_T_w_c is not None:
        out["ate_rmse_m"] = ate(T, seq.gt_T_w_c[:n])["rmse_m"]
        out["rpe_t_m_per_frame"] = rpe(T, seq.gt_T_w_c[:n])["t_rmse_m"]
    if prof:
        pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seq", nargs="+", default=[str(DEFAULT_SEQ)], help="sequence folders")
    ap.add_argument("--sim", default="static", help="also simulate this scenario at 640x480 ('none': skip)")
    ap.add_argument("--sim-frames", type=int, default=100, help="frames of the simulated sequence")
    ap.add_argument("--mode", default="static", choices=["static", "masked"])
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--profile", action="store_true", help="print the cProfile top functions")
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                    help="stage timings in wall time or in process CPU time (steadier on a shared machine)")
    args = ap.parse_args()
    if args.clock == "cpu":
        time.perf_counter = time.process_time  # read by System's stage timers through the time module
    seqs = [s for s in args.seq if Path(s).is_dir()]
    tmp = tempfile.TemporaryDirectory(prefix="bench-slam-")
    if args.sim != "none":
        from sim.generate import generate_sequence  # benchmarks may use the simulator
        from sim.scenarios import load_scenario

        cfg = load_scenario(args.sim, [f"frames={args.sim_frames}", "image_size=640x480", "seed=0"])
        seqs.append(str(generate_sequence(cfg, Path(tmp.name) / args.sim, progress=False)))
    for seq in seqs:
        r = bench(Path(seq), args.mode, args.frames, args.overrides, args.profile)
        print(f"{r['sequence']} ({r['size']}, {r['frames']} frames, {r['keyframes']} keyframes, {r['lost']} lost, "
              f"mode {args.mode})")
        print("  median ms per frame: " + ", ".join(f"{k} {v:.1f}" for k, v in r["median_ms"].items()))
        print("  median ms per keyframe: " + ", ".join(f"{k} {v:.1f}" for k, v in r["median_ms_keyframes"].items()))
        print(f"  fps {r['fps']:.2f} (SLAM time), {r['wall_fps']:.2f} (wall), {r['cpu_fps']:.2f} (CPU time)")
        if "ate_rmse_m" in r:
            print(f"  ATE RMSE {r['ate_rmse_m']:.4f} m, RPE_t {r['rpe_t_m_per_frame']:.4f} m/frame")
    tmp.cleanup()


if __name__ == "__main__":
    main()
