"""`dynaslam2 eval`: score a results folder against its sequence's ground truth (metrics.json keys of DESIGN.md).

- ego.ate_rmse_m: RMSE of the position errors after SE(3) Umeyama alignment, over ALL frames
  (frames flagged lost still have a pose in poses.txt and are scored as written).
- ego.rpe_t_m_per_frame / ego.rpe_r_deg_per_frame: RMSE (evo's headline statistic) of the relative
  translation (m) and rotation (deg) errors over the consecutive frame pairs (i, i+1).
- ego.frames: frames scored; ego.lost_frames: frames whose status state is "lost".
- objects.*: only when the run wrote objects (objects.jsonl, the `dynamic` mode) and the sequence has
  GT objects in some frame; definitions in eval/objects.py (per-track ATE/RPE after a per-track
  frame offset, TP ratio, id switches; GT tracks within 30 m).
- timing.median_ms.<stage>: median over the frames of each stage of timing.csv;
  timing.fps = frames / summed total time: end-to-end throughput, keyframes' local mapping included
  (null when no time was recorded).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from dynaslam2.errors import InputError
from dynaslam2.eval.objects import ObjectEvalConfig, evaluate_object_tracks
from dynaslam2.eval.trajectory import ate, rpe
from dynaslam2.io.atomic import write_text_atomic
from dynaslam2.io.results import POSES_FILE, read_results
from dynaslam2.io.sequence import open_sequence


def evaluate(seq_path: str | os.PathLike, res_path: str | os.PathLike,
             object_config: ObjectEvalConfig = ObjectEvalConfig()) -> dict:
    """Nested metrics dict of a results folder `res_path` scored against the sequence `seq_path`
    (`object_config`: the thresholds of the objects section)."""
    seq_path, res_path = Path(seq_path), Path(res_path)
    results = read_results(res_path)
    seq = open_sequence(seq_path)
    recorded, fingerprint = (results.run or {}).get("sequence_fingerprint"), seq.fingerprint()
    if recorded is not None and recorded != fingerprint:
        raise InputError(f"{res_path} holds results of {results.run.get('sequence', 'another sequence')}, not of "
                         f"{seq_path} (run.json's sequence_fingerprint {recorded} differs from {fingerprint})")
    if seq.gt_T_w_c is None:
        raise InputError(f"no ground-truth trajectory in {seq_path}: expected {seq_path / 'poses.txt'}")
    T_gt = np.asarray(seq.gt_T_w_c, dtype=float)
    if len(results) != len(T_gt):
        raise InputError(f"{res_path / POSES_FILE} has {len(results)} frames but the ground truth of "
                         f"{seq_path} has {len(T_gt)}")
    if len(results) == 0:
        raise InputError(f"{res_path / POSES_FILE} holds no frame")
    ate_m = ate(results.T_w_c, T_gt, align="se3")
    rpe_1 = rpe(results.T_w_c, T_gt, delta=1)
    total_ms = float(np.sum(results.timing["total"]))
    metrics = {
        "ego": {
            "ate_rmse_m": ate_m["rmse_m"],
            "rpe_t_m_per_frame": rpe_1["t_rmse_m"],
            "rpe_r_deg_per_frame": rpe_1["r_rmse_deg"],
            "frames": len(results),
            "lost_frames": sum(s["state"] == "lost" for s in results.status),
        },
    }
    if results.has_objects:
        gt_objects = [seq.gt_objects(i) for i in range(len(seq))]
        if any(gt_objects):
            metrics["objects"] = evaluate_object_tracks(gt_objects, T_gt, seq.timestamps, results.objects,
                                                        results.T_w_c, object_config)
    metrics["timing"] = {
        "median_ms": {stage: float(np.median(ms)) for stage, ms in results.timing.items()},
        "fps": 1000.0 * len(results) / total_ms if total_ms > 0.0 else None,
    }
    return metrics


def _flatten(tree: dict, prefix: str = "") -> list[tuple[str, object]]:
    rows = []
    for key, value in tree.items():
        name = f"{prefix}{key}"
        rows.extend(_flatten(value, name + ".") if isinstance(value, dict) else [(name, value)])
    return rows


def format_table(metrics: dict) -> str:
    """Two-column text table of the metrics, one dotted key per line (lists, e.g. a track's switch frames, as JSON)."""
    rows = [(name, "-" if v is None else v if isinstance(v, int) else json.dumps(v) if isinstance(v, list)
             else f"{v:.4f}") for name, v in _flatten(metrics)]
    width = max(len(name) for name, _ in rows)
    lines = [f"{'metric':<{width}}  value", f"{'-' * width}  -----"]
    lines += [f"{name:<{width}}  {value}" for name, value in rows]
    return "\n".join(lines)


def write_metrics(path: str | os.PathLike, metrics: dict) -> None:
    """Write the metrics as indented JSON, atomically."""
    try:
        write_text_atomic(Path(path), json.dumps(metrics, indent=2) + "\n")
    except OSError as exc:
        raise InputError(f"cannot write metrics file {path}: {exc.strerror or exc}") from None
