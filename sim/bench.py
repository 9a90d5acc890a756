"""Throughput of sequence generation (full output: stereo RGB + depth + instances + GT, written to disk).

`dynaslam2 bench sim` prints, per image size, the median milliseconds per frame of every stage, the
wall and CPU milliseconds per frame and the end-to-end frames per second of the frame loop (writing
overlaps rendering, so the stages do not add up to the frame time). The CPU time and the load
average are printed because the wall time depends on what else runs on the machine.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from sim.generate import GenerationStats, generate_sequence
from sim.render import RenderConfig
from sim.scenarios import load_scenario

STAGES = ("left_rgb", "right_rgb", "seg_depth", "amodal", "gt", "write")


def bench_sim(frames: int = 30, sizes: list[str] | tuple[str, ...] = ("640x480", "1242x375"),
              progress: bool = True, scenario: str = "traffic",
              render_cfg: RenderConfig = RenderConfig()) -> list[dict]:
    """Generate `frames` frames of `scenario` at each size into a temporary folder, rendered with `render_cfg`;
    print and return the table."""
    rows = []
    for size in sizes:
        cfg = load_scenario(scenario, [f"frames={frames}", f"image_size={size}"])
        stats = GenerationStats()
        with tempfile.TemporaryDirectory(prefix="dynaslam2-bench-") as tmp:
            generate_sequence(cfg, Path(tmp) / "seq", progress=progress, render_cfg=render_cfg, stats=stats)
        row = {"size": f"{cfg.image_size[0]}x{cfg.image_size[1]}", "frames": stats.frames,
               "setup_s": stats.setup_s, "fps": stats.frames / stats.loop_s,
               "frame_ms": stats.loop_s / stats.frames * 1e3,
               "cpu_ms": stats.loop_cpu_s / stats.frames * 1e3}
        row.update({s: float(np.median(stats.stage_ms.get(s, [np.nan]))) for s in STAGES})
        rows.append(row)
    header = f"{'size':>10} {'frames':>6} " + " ".join(f"{s:>9}" for s in STAGES) + f" {'frame':>8} {'cpu':>8} {'fps':>6}"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"sim bench: scenario '{scenario}', msaa_samples {render_cfg.msaa_samples}, median wall ms per frame per "
          "stage (write overlaps rendering); "
          f"frame = wall ms per frame, cpu = CPU ms per frame of all threads; {os.cpu_count()} CPUs, load {load:.1f}")
    print(header)
    for r in rows:
        print(f"{r['size']:>10} {r['frames']:>6} " + " ".join(f"{r[s]:9.1f}" for s in STAGES)
              + f" {r['frame_ms']:8.1f} {r['cpu_ms']:8.1f} {r['fps']:6.2f}")
    return rows
