"""Generate a sequence: build the world, render and compute ground truth per frame, write it to disk.

Writing frame i (PNG encoding releases the GIL) overlaps with rendering frame i+1 in one worker
thread; frames are written strictly in order, so the output is byte-identical for the same seed and
a crash keeps frames 0..k-1 readable.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dynaslam2.config_tree import to_dict
from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.io.sequence import SequenceWriter
from dynaslam2.io.types import FrameData
from dynaslam2.versions import package_versions
from sim.groundtruth import GroundTruth, GroundTruthConfig
from sim.render import RenderConfig, StereoRenderer
from sim.scenarios import ScenarioConfig
from sim.world import build_world, camera_intrinsics


@dataclass
class GenerationStats:
    """Per-stage milliseconds per frame (render passes, gt, write) and the wall time of the frame loop."""

    stage_ms: dict[str, list[float]] = field(default_factory=dict)
    setup_s: float = 0.0
    loop_s: float = 0.0
    loop_cpu_s: float = 0.0  # CPU time of all threads of the process (GL rasterizer threads included)
    frames: int = 0

    def add(self, stage: str, ms: float) -> None:
        self.stage_ms.setdefault(stage, []).append(ms)


def sim_versions() -> dict[str, str]:
    """Versions of the packages and of the sim world that determine the output bytes."""
    import mujoco

    from sim.world import WORLD_VERSION

    return package_versions(mujoco=mujoco.__version__, sim_world=str(WORLD_VERSION))


def sequence_meta(cfg: ScenarioConfig, render_cfg: RenderConfig, gt_cfg: GroundTruthConfig) -> dict:
    """meta.json content: scenario config, seed, versions, image size, fps (no timestamps: deterministic)."""
    return {
        "generator": "sim.generate",
        "scenario": to_dict(cfg),
        "seed": int(cfg.seed),
        "fps": float(cfg.fps),
        "image_size": [int(v) for v in cfg.image_size],
        "render": to_dict(render_cfg),
        "groundtruth": to_dict(gt_cfg),
        "versions": sim_versions(),
    }


def generate_sequence(
    cfg: ScenarioConfig,
    out: Path,
    overwrite: bool = False,
    preview: bool = False,
    progress: bool = True,
    render_cfg: RenderConfig = RenderConfig(),
    gt_cfg: GroundTruthConfig = GroundTruthConfig(),
    stats: GenerationStats | None = None,
) -> Path:
    """Simulate `cfg` and write the sequence to `out`; returns `out`.

    Everything is validated (config, world, calibration, output folder) before the first file is
    written. `stats`, when given, collects per-stage timings (used by `sim.bench`).
    """
    if not isinstance(cfg, ScenarioConfig):
        raise InputError(f"generate_sequence: expected a ScenarioConfig, got {type(cfg).__name__}")
    cfg.validate()
    render_cfg.validate()
    out = Path(out)
    stats = stats if stats is not None else GenerationStats()
    t_setup = time.perf_counter()
    world = build_world(cfg)
    width, height = (int(v) for v in cfg.image_size)
    intrinsics = tuple(float(v) for v in camera_intrinsics(cfg))
    camera = StereoCamera(*intrinsics, float(cfg.baseline), width, height)
    gt = GroundTruth(world, camera, gt_cfg)
    meta = sequence_meta(cfg, render_cfg, gt_cfg)
    renderer = StereoRenderer(world, width, height, render_cfg)
    with renderer:
        renderer.ensure_context()  # a GL failure must not leave a half-written folder
        stats.setup_s = time.perf_counter() - t_setup
        with SequenceWriter(out, camera, meta, overwrite=overwrite, with_depth=cfg.depth) as writer, \
                ThreadPoolExecutor(max_workers=1, thread_name_prefix="sequence-writer") as pool:
            _frame_loop(cfg, world, renderer, gt, intrinsics, writer, pool, progress, stats)
    if preview:
        from sim.preview import write_preview

        write_preview(out, progress=progress)
    return out


def _frame_loop(cfg: ScenarioConfig, world, renderer: StereoRenderer, gt: GroundTruth, intrinsics: tuple,
                writer: SequenceWriter, pool: ThreadPoolExecutor, progress: bool, stats: GenerationStats) -> None:
    """Render, compute GT and hand each frame to the writer thread (one frame in flight)."""

    def write(frame: FrameData, T_w_c: np.ndarray, objects: list) -> None:
        t0 = time.perf_counter()
        writer.write_frame(frame, T_w_c, objects)
        stats.add("write", (time.perf_counter() - t0) * 1e3)

    pending: Future | None = None
    t_loop, cpu_loop = time.perf_counter(), time.process_time()
    bar = tqdm(total=cfg.frames, desc=f"simulate {cfg.name}", unit="frame", disable=not progress, leave=False)
    try:
        for i in range(cfg.frames):
            t = i / cfg.fps
            world.set_time(t)
            T_w_c, T_m_c = gt.camera_pose(t)
            rendered = renderer.render(T_m_c, intrinsics, right=True, depth=cfg.depth)
            t0 = time.perf_counter()
            objects = gt.objects(t, T_w_c, rendered.visible_px, rendered.amodal_px, rendered.box2d)
            stats.add("gt", (time.perf_counter() - t0) * 1e3)
            for stage, ms in rendered.timings_ms.items():
                stats.add(stage, ms)
            frame = FrameData(index=i, timestamp=t, left=rendered.left, right=rendered.right,
                              depth=rendered.depth, instances=rendered.instances)
            if pending is not None:
                pending.result()  # at most one frame in flight; re-raises a write error
            pending = pool.submit(write, frame, T_w_c, objects)
            bar.update(1)
        if pending is not None:
            pending.result()
    finally:
        bar.close()
    stats.loop_s = time.perf_counter() - t_loop
    stats.loop_cpu_s = time.process_time() - cpu_loop
    stats.frames = cfg.frames
