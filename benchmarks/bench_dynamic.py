"""The three modes side by side on simulated sequences (issue 4's proof): ego ATE of `static`,
`masked` and `dynamic`, the objects within 30 m (object ATE, TP ratio, id switches) of `dynamic`,
end-to-end fps and median local BA per keyframe of each mode. The object figures are given twice:
every listed object within 30 m (eval's defaults), and the paper's Table IV selection within 30 m
(`PAPER_PROTOCOL`: frames where the object is unoccluded, untruncated and >= 40 px high; columns "p*").
Issue 4's id criteria (`UNOCCLUDED_PROTOCOL`): "uidsw", the id switches while the object is unoccluded
(KITTI occlusion level 0) within 30 m, each listed after the table (GT track, frame, estimated ids); "gaps",
occlusions of <= 1 s (tracked before and after) that kept the id / all of them.

    python benchmarks/bench_dynamic.py [--scenarios traffic crossing following static] [--seeds 0 1]
        [--frames 150] [--size 640x480] [--modes static masked dynamic] [--work DIR] [--set k=v ...]
        [--sim-set k=v ...]

--set overrides the SLAM config, --sim-set the scenario (sim.scenarios.ScenarioConfig): e.g. KITTI's
camera geometry is `--size 1242x375 --sim-set fx=721.5` (baseline 0.54 m is the default).

Sequences are generated once into --work (default /tmp/bench_dynamic) and reused. For each sequence
the modes run one after the other on frames loaded beforehand (disk reads are not SLAM time); fps =
frames / summed per-frame `total` (tracking + objects + local mapping + BA, one process). Timings on
a shared machine move with its load: compare modes within one sequence. What dominates: the mean ms
per frame of each stage of System.process (features = ORB, stereo = matching and row search, tracking
= camera, objects = object tracking, local_ba = local mapping with its BA), and dynamic minus static.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from dynaslam2.config import load_config
from dynaslam2.errors import InputError
from dynaslam2.eval.objects import PAPER_PROTOCOL, UNOCCLUDED_PROTOCOL, evaluate_objects
from dynaslam2.eval.trajectory import ate
from dynaslam2.io.sequence import open_sequence
from dynaslam2.system import System
from sim.scenarios import load_scenario
from sim.world import WORLD_VERSION


def ensure_sequence(work: Path, scenario: str, seed: int, frames: int, size: str,
                    sim_overrides: tuple[str, ...] = ()) -> Path:
    """The sequence's folder under `work`, generated on first use; the sim's world version and scenario
    overrides (`sim_overrides`, e.g. "fx=721.5") are part of its name, so each world or camera variant is
    cached apart and a changed world is regenerated."""
    suffix = "".join("_" + "".join(c if c.isalnum() or c in ".-" else "-" for c in o) for o in sim_overrides)
    out = work / f"{scenario}_s{seed}_{frames}_{size}_w{WORLD_VERSION}{suffix}"
    if not (out / "meta.json").exists():
        os.environ.setdefault("MUJOCO_GL", "egl")
        from sim.generate import generate_sequence

        cfg = load_scenario(scenario, [f"seed={seed}", f"frames={frames}", f"image_size={size}", *sim_overrides])
        generate_sequence(cfg, out, overwrite=True, preview=False, progress=False)
    return out


# System.process's per-frame timings (timing.csv's stages; "local_ba" is the whole local mapping of a keyframe)
STAGES = ("features", "stereo", "tracking", "objects", "local_ba", "total")


def run_mode(seq, data: list, mode: str, overrides: list[str]) -> dict:
    system = System(load_config(None, overrides + [f"mode={mode}"]), seq.camera)
    estimates = [system.process(frame) for frame in data]
    T = np.array([e.T_w_c for e in estimates])
    ba = [e.mapping_ms.get("ba", 0.0) for e in estimates if e.keyframe and e.mapping_ms]
    out = {
        "ate": ate(T, seq.gt_T_w_c[: len(data)])["rmse_m"],
        "fps": len(data) / (sum(e.timing_ms["total"] for e in estimates) / 1e3),
        "ba_ms": float(np.median(ba)) if ba else 0.0,
        "lost": sum(e.state == "lost" for e in estimates),
        "objects_ms": float(np.median([e.timing_ms["objects"] for e in estimates])),
        "stage_ms": {k: float(np.mean([e.timing_ms[k] for e in estimates])) for k in STAGES},
    }
    if mode == "dynamic":
        objects = [e.objects for e in estimates]
        m = evaluate_objects(seq, objects, T) if len(data) == len(seq) else None
        if m is not None:
            out.update(obj_ate=m["ate_rmse_m"], obj_ate_cam=m["ate_cam_rmse_m"], tp=m["tp_ratio"],
                       id_sw=m["id_switches"], reid_sw=m["reid_switches"], gt_tracks=m["gt_tracks"])
            p = evaluate_objects(seq, objects, T, PAPER_PROTOCOL)
            out.update(p_obj_ate=p["ate_rmse_m"], p_tp=p["tp_ratio"], p_id_sw=p["id_switches"],
                       p_gt_tracks=p["gt_tracks"])
            u = evaluate_objects(seq, objects, T, UNOCCLUDED_PROTOCOL)
            out.update(u_id_sw=u["id_switches"], gaps=u["short_gaps"], gaps_kept=u["short_gaps_kept"],
                       u_switches=[(gid, *s) for gid, row in u["per_track"].items() for s in row["id_switch_frames"]])
    return out


def fmt(v, spec: str = ".3f") -> str:
    return "-" if v is None else format(v, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["traffic", "crossing", "following", "static"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--modes", nargs="+", default=["static", "masked", "dynamic"])
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_dynamic"))
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--sim-set", dest="sim_overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    try:  # bad keys or values: one line before any sequence is made
        load_config(None, args.overrides)
        for scenario in args.scenarios:
            load_scenario(scenario, [f"frames={args.frames}", f"image_size={args.size}", *args.sim_overrides])
    except InputError as e:
        ap.error(str(e))
    args.work.mkdir(parents=True, exist_ok=True)
    modes = args.modes
    head = (["scenario", "seed"] + [f"ATE {m[:3]}" for m in modes]
            + ["obj ATE", "obj ATEcam", "TP", "idsw", "reid", "uidsw", "gaps", "pATE", "pTP", "pidsw", "ptracks"]
            + [f"fps {m[:3]}" for m in modes] + [f"BA ms {m[:3]}" for m in modes] + ["obj ms"])
    print("  ".join(f"{h:>10}" for h in head), flush=True)
    rows = []
    for scenario in args.scenarios:
        for seed in args.seeds:
            seq_path = ensure_sequence(args.work, scenario, seed, args.frames, args.size, tuple(args.sim_overrides))
            seq = open_sequence(seq_path)
            data = [seq[i] for i in range(len(seq))]
            r = {m: run_mode(seq, data, m, args.overrides) for m in modes}
            rows.append((scenario, seed, r))
            d = r.get("dynamic", {})
            cells = ([scenario, str(seed)] + [fmt(r[m]["ate"]) for m in modes]
                     + [fmt(d.get("obj_ate")), fmt(d.get("obj_ate_cam")), fmt(d.get("tp"), ".2f"),
                        fmt(d.get("id_sw"), "d"), fmt(d.get("reid_sw"), "d"), fmt(d.get("u_id_sw"), "d"),
                        f"{d['gaps_kept']}/{d['gaps']}" if "gaps" in d else "-",
                        fmt(d.get("p_obj_ate")), fmt(d.get("p_tp"), ".2f"), fmt(d.get("p_id_sw"), "d"),
                        fmt(d.get("p_gt_tracks"), "d")]
                     + [fmt(r[m]["fps"], ".2f") for m in modes] + [fmt(r[m]["ba_ms"], ".0f") for m in modes]
                     + [fmt(d.get("objects_ms"), ".1f")])
            print("  ".join(f"{c:>10}" for c in cells), flush=True)
    dyn = [r["dynamic"] for _, _, r in rows if "obj_ate" in r.get("dynamic", {})]
    if dyn:
        for label, k in (("all within 30 m", ""), ("paper protocol", "p_")):
            ates = [d[k + "obj_ate"] for d in dyn if d[k + "obj_ate"] is not None]
            tps = [d[k + "tp"] for d in dyn if d[k + "tp"] is not None]
            print(f"objects, {label} (means over sequences): object ATE {np.mean(ates):.3f} m, TP {np.mean(tps):.3f}, "
                  f"id switches {sum(d[k + 'id_sw'] for d in dyn)}, GT tracks {sum(d[k + 'gt_tracks'] for d in dyn)}")
        print(f"objects, issue 4's id criteria: id switches while unoccluded {sum(d['u_id_sw'] for d in dyn)}, "
              f"occlusions <= 1 s keeping the id {sum(d['gaps_kept'] for d in dyn)}/{sum(d['gaps'] for d in dyn)}")
        for scenario, seed, r in rows:
            for gid, frame, old_id, new_id in r["dynamic"].get("u_switches", []):
                print(f"  unoccluded id switch: {scenario} seed {seed}, GT track {gid} at frame {frame}: "
                      f"estimated track {old_id} -> {new_id}")
    print("ego ATE means over sequences: " + ", ".join(f"{m} {np.mean([r[m]['ate'] for _, _, r in rows]):.4f} m"
                                                      for m in modes))
    if {"masked", "dynamic"} <= set(modes):
        better = sum(r["dynamic"]["ate"] <= r["masked"]["ate"] for _, _, r in rows)
        diff = np.array([r["dynamic"]["ate"] - r["masked"]["ate"] for _, _, r in rows]) * 1e3
        se = f", standard error {diff.std(ddof=1) / np.sqrt(len(diff)):.1f} mm" if len(diff) > 1 else ""
        print(f"dynamic ego ATE <= masked on {better}/{len(rows)} sequences; paired difference dynamic - masked "
              f"{diff.mean():+.1f} mm{se}")
    if {"static", "dynamic"} <= set(modes):
        ratio = [r["dynamic"]["ate"] / r["static"]["ate"] for _, _, r in rows]
        print("dynamic/static ego ATE: " + ", ".join(f"{s}{k}: {x:.2f}" for (s, k, _), x in zip(rows, ratio)))
        fps = [r["dynamic"]["fps"] / r["static"]["fps"] for _, _, r in rows]
        print(f"dynamic/static fps: median {np.median(fps):.2f}")
    print("ms per frame by stage (each sequence's mean, median over sequences):")
    for m in modes:
        print(f"  {m:8s} " + ", ".join(f"{k} {np.median([r[m]['stage_ms'][k] for _, _, r in rows]):.1f}"
                                       for k in STAGES))
    if {"static", "dynamic"} <= set(modes):
        extra = {k: [r["dynamic"]["stage_ms"][k] - r["static"]["stage_ms"][k] for _, _, r in rows] for k in STAGES}
        print("  dynamic - static: " + ", ".join(f"{k} {np.median(v):+.1f}" for k, v in extra.items()))


if __name__ == "__main__":
    main()
