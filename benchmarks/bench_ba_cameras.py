"""What the BA with objects does to the cameras (issue 4: does tracking objects improve the ego-motion?).

    python benchmarks/bench_ba_cameras.py [--scenario following] [--seeds 0 1 2 3 4] [--frames 150]
        [--size 640x480] [--work DIR] [--set k=v ...]

Runs the `dynamic` mode on simulated sequences (bench_dynamic's, generated once into --work). Every window
given to the BA with objects (mapping.objects.object_local_ba) is also solved, from the same input, as
- "static": the static local BA alone (the objects left out: paper III-D's camera-weak-only case), for the
  joint windows (camera and objects weak);
- "no eq4": the same BA with eq. (4)-(5) made negligible (optim.objects.sigma_motion_xyz = 1e4), the only terms
  through which the objects reach the cameras (eq. 2 is on T_o_c, object_ba's docstring);
and the run goes on with the BA's own result. For each: the keyframe-to-keyframe camera error against ground
truth (eval.trajectory.rpe's translation error over the window's keyframes in time order, on the pairs with a
free keyframe), mean in mm, over the joint and the object-weak windows of all sequences.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

import dynaslam2.mapping.objects as mapping_objects
from dynaslam2.config import load_config
from dynaslam2.errors import InputError
from dynaslam2.eval.trajectory import rpe
from dynaslam2.geometry.se3 import inverse
from dynaslam2.io.sequence import open_sequence
from dynaslam2.optim.object_ba import object_bundle_adjustment
from dynaslam2.system import System

from bench_dynamic import ensure_sequence  # this script's folder (python benchmarks/bench_ba_cameras.py)


def keyframe_errors(T_c_w: np.ndarray, T_w_c_gt: np.ndarray, order: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(R,) translation error (m) of each consecutive keyframe pair (time `order`) selected by `pairs`."""
    return rpe(inverse(T_c_w[order]), T_w_c_gt[order])["t_errors_m"][pairs]


def run_sequence(seq, cfg, rows: list[dict]) -> None:
    """The dynamic mode on `seq`; appends one row per BA-with-objects window."""
    no_eq4 = dataclasses.replace(cfg.optim, objects=dataclasses.replace(cfg.optim.objects, sigma_motion_xyz=1e4))
    timestamps = np.asarray(seq.timestamps)

    def compared(problem, camera, optim_cfg):
        result = object_bundle_adjustment(problem, camera, optim_cfg)
        order = np.argsort(problem.timestamps)
        pairs = ~(problem.fixed[order[:-1]] & problem.fixed[order[1:]])
        frames = np.abs(timestamps[None, :] - problem.timestamps[:, None]).argmin(axis=1)
        gt = seq.gt_T_w_c[frames]
        row = {"joint": problem.optimize_static,
               "input": keyframe_errors(problem.T_c_w, gt, order, pairs),
               "BA": keyframe_errors(result.T_c_w, gt, order, pairs),
               "no eq4": keyframe_errors(object_bundle_adjustment(problem, camera, no_eq4).T_c_w, gt, order, pairs)}
        if problem.optimize_static:
            static = object_bundle_adjustment(dataclasses.replace(problem, optimize_objects=False), camera, optim_cfg)
            row["static"] = keyframe_errors(static.T_c_w, gt, order, pairs)
        rows.append(row)
        return result

    mapping_objects.object_bundle_adjustment = compared  # this benchmark's own process only
    system = System(cfg, seq.camera)
    for i in range(len(seq)):
        system.process(seq[i])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="following")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_dynamic"))
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    try:
        cfg = load_config(None, args.overrides + ["mode=dynamic"])
    except InputError as e:
        ap.error(str(e))
    args.work.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    for seed in args.seeds:
        seq = open_sequence(ensure_sequence(args.work, args.scenario, seed, args.frames, args.size))
        run_sequence(seq, cfg, rows)
    for joint, label in ((True, "joint (camera and objects weak)"), (False, "object-weak only")):
        sel = [r for r in rows if r["joint"] == joint]
        if not sel:
            continue
        keys = [k for k in ("input", "BA", "static", "no eq4") if k in sel[0]]
        means = ", ".join(f"{k} {1e3 * np.mean(np.concatenate([r[k] for r in sel])):.3f}" for k in keys)
        n_pairs = sum(len(r["input"]) for r in sel)
        print(f"{args.scenario} seeds {args.seeds}, {label}: {len(sel)} windows, {n_pairs} keyframe pairs; "
              f"mean keyframe-to-keyframe camera error, mm: {means}")


if __name__ == "__main__":
    main()
