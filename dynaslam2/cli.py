"""The `dynaslam2` command: simulate, run, eval, demo, sweep, bench.

This is the one module that ties `dynaslam2`, `sim` and `envs` together; it imports `sim` lazily,
inside the subcommands that need it, so the SLAM library never depends on MuJoCo.
Bad input (InputError) is reported as one line on stderr with exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from dynaslam2 import __version__
from dynaslam2.errors import InputError

DEMO_FRAMES = 60
DEMO_SCENARIO = "traffic"
DEMO_MODE = "dynamic"


def _add_sim_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="traffic",
                   help="built-in scenario (static, traffic, crossing, following) or a YAML file (default: traffic)")
    p.add_argument("--seed", type=int, default=None, help="random seed: same seed, same sequence")
    p.add_argument("--frames", type=int, default=None, help="number of frames to generate")
    p.add_argument("--size", default=None, metavar="WxH", help="image size, e.g. 640x480 or 1242x375")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override any scenario field, e.g. --set object_speed=2.0 (repeatable)")


def _scenario_from_args(args: argparse.Namespace):
    from sim.scenarios import load_scenario

    overrides = list(args.overrides)
    if args.seed is not None:
        overrides.append(f"seed={args.seed}")
    if args.frames is not None:
        overrides.append(f"frames={args.frames}")
    if args.size is not None:
        overrides.append(f"image_size={args.size}")
    return load_scenario(args.scenario, overrides)


def _add_render_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--render-set", dest="render_overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a rendering setting (sim.render.RenderConfig), e.g. --render-set msaa_samples=0 "
                        "for aliased colour images, 1.6-1.8x faster (repeatable)")


def cmd_simulate(args: argparse.Namespace) -> int:
    from sim.generate import generate_sequence
    from sim.render import load_render_config

    cfg = _scenario_from_args(args)
    render_cfg = load_render_config(args.render_overrides)
    out = generate_sequence(cfg, Path(args.out), overwrite=args.overwrite, preview=args.preview,
                            progress=not args.quiet, render_cfg=render_cfg)
    if not args.quiet:
        print(f"wrote {cfg.frames} frames of '{cfg.name}' (seed {cfg.seed}) to {out}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from dynaslam2.eval.report import evaluate, format_table, write_metrics
    from dynaslam2.io.results import METRICS_FILE
    from dynaslam2.runner import run_sequence
    from sim.generate import generate_sequence
    from sim.scenarios import load_scenario

    cfg = load_scenario(DEMO_SCENARIO, [f"frames={args.frames}"])
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="dynaslam2-demo-"))
    seq = generate_sequence(cfg, out / "sequence", overwrite=True, preview=True, progress=not args.quiet)
    print(f"demo: simulated {cfg.frames} frames of the '{cfg.name}' scenario into {seq}")
    print(f"demo: preview video {seq / 'preview.mp4'} and contact sheet {seq / 'preview.png'}")
    res = run_sequence(seq, args.mode, out / f"results-{args.mode}", overwrite=True, progress=not args.quiet)
    metrics = evaluate(seq, res)
    write_metrics(res / METRICS_FILE, metrics)
    summary = {section: {k: v for k, v in values.items() if k != "per_track"} for section, values in metrics.items()}
    print(f"demo: '{args.mode}' SLAM results in {res}; scores against the ground truth "
          f"(per-track object scores in {res / METRICS_FILE}):")
    print(format_table(summary))
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from dynaslam2.runner import run_sequence

    out = run_sequence(args.seq, args.mode, args.out, config_path=args.config, overrides=args.overrides,
                       overwrite=args.overwrite, progress=not args.quiet)
    if not args.quiet:
        print(f"wrote results of '{args.mode}' mode to {out}")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from dynaslam2.eval.report import evaluate, format_table, write_metrics
    from dynaslam2.io.results import METRICS_FILE

    metrics = evaluate(args.seq, args.res)
    out = Path(args.json) if args.json else Path(args.res) / METRICS_FILE
    write_metrics(out, metrics)
    print(format_table(metrics))
    if not args.quiet:
        print(f"wrote {out}")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from dynaslam2.sweep import SUMMARY_FILE, SweepSpec, format_summary, parse_grid, run_sweep

    sim_overrides = list(args.overrides)
    if args.frames is not None:
        sim_overrides.append(f"frames={args.frames}")
    if args.size is not None:
        sim_overrides.append(f"image_size={args.size}")
    spec = SweepSpec(scenario=args.scenario, grid=parse_grid(args.grid), seeds=args.seeds, modes=list(args.modes),
                     sim_overrides=sim_overrides, slam_overrides=list(args.slam_overrides))
    rows = run_sweep(spec, args.out, backend=args.backend, jobs=args.jobs, progress=not args.quiet)
    print(format_summary(spec, rows))
    failed = [r for r in rows if r["status"] != "ok"]
    print(f"sweep: {len(rows) - len(failed)} of {len(rows)} runs scored; {Path(args.out) / SUMMARY_FILE}")
    for r in failed:
        print(f"sweep: {r['job']} {r['mode']}: {r['status']}", file=sys.stderr)
    return 1 if failed else 0


def cmd_bench(args: argparse.Namespace) -> int:
    if args.target == "sim":
        from sim.bench import bench_sim
        from sim.render import load_render_config

        bench_sim(frames=args.frames, sizes=args.sizes, progress=not args.quiet,
                  render_cfg=load_render_config(args.render_overrides))
        return 0
    raise InputError(f"bench: unknown target {args.target!r}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dynaslam2",
        description="DynaSLAM II in Python: stereo/RGB-D SLAM that tracks moving objects, "
                    "and a MuJoCo street world that generates sequences with exact ground truth.",
    )
    parser.add_argument("--version", action="version", version=f"dynaslam2 {__version__}")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("simulate", help="generate a synthetic stereo sequence with ground truth",
                       description="Render a street scenario (stereo RGB, depth, instance masks) and write it "
                                   "with full ground truth in KITTI-compatible files.")
    _add_sim_args(p)
    p.add_argument("--out", required=True, help="output sequence folder")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    p.add_argument("--preview", action="store_true", help="also write preview.mp4 and a preview.png contact sheet")
    _add_render_arg(p)
    p.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("demo", help="simulate the default scenario, run SLAM on it and print the scores",
                       description=f"Simulate the default '{DEMO_SCENARIO}' scenario (with a preview video and "
                                   "contact sheet), run SLAM on it and print its scores against the ground truth.")
    p.add_argument("--frames", type=int, default=DEMO_FRAMES, help=f"frames to simulate (default {DEMO_FRAMES})")
    p.add_argument("--out", default=None, help="output folder (default: a new temporary folder)")
    p.add_argument("--mode", choices=["dynamic", "masked", "static"], default=DEMO_MODE,
                   help=f"SLAM mode (default {DEMO_MODE})")
    p.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="run SLAM on a sequence and write the results files",
                       description="Track the stereo/RGB-D sequence SEQ frame by frame and write RES/poses.txt, "
                                   "RES/status.jsonl and RES/timing.csv (written as it goes).")
    p.add_argument("seq", metavar="SEQ", help="sequence folder (ours, KITTI odometry or KITTI tracking)")
    p.add_argument("--mode", required=True, choices=["dynamic", "masked", "static"],
                   help="static: every feature; masked: no features on dynamic-class instances; "
                        "dynamic: DynaSLAM II object tracking (objects.jsonl, tracks.txt)")
    p.add_argument("--out", required=True, metavar="RES", help="results folder")
    p.add_argument("--config", default=None, metavar="FILE", help="YAML file with SLAM config overrides")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a SLAM config value, e.g. --set tracking.min_inliers=40 (repeatable)")
    p.add_argument("--overwrite", action="store_true", help="replace the results in a non-empty RES")
    p.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("eval", help="score a run's results against the sequence's ground truth",
                       description="Compare RES (written by `dynaslam2 run`) with the ground truth of SEQ: "
                                   "ATE after SE(3) Umeyama alignment, RPE per frame pair (m, deg), lost "
                                   "frames, median stage timings and fps. Prints a table and writes "
                                   "RES/metrics.json.")
    p.add_argument("seq", metavar="SEQ", help="sequence folder with ground-truth poses.txt")
    p.add_argument("res", metavar="RES", help="results folder of `dynaslam2 run`")
    p.add_argument("--json", default=None, metavar="FILE", help="write the metrics here instead of RES/metrics.json")
    p.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("sweep", help="simulate a grid of scenarios x seeds, run the modes, score and tabulate",
                       description="Every grid point (scenario fields, or SLAM config keys prefixed slam.) is "
                                   "simulated for seeds 0..N-1, run in each mode and scored; OUT/summary.csv has a row "
                                   "per run. Runs in parallel on local processes or Ray; a rerun resumes.")
    p.add_argument("--scenario", default="traffic",
                   help="built-in scenario (static, traffic, crossing, following) or a YAML file (default: traffic)")
    p.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a swept key and its values, e.g. --grid object_speed=0.5,1,2 or --grid "
                        "slam.objects.ba=true,false (repeatable: the grid is their product)")
    p.add_argument("--seeds", type=int, default=1, help="seeds 0..N-1 per grid point (default 1)")
    p.add_argument("--modes", nargs="+", default=["dynamic", "masked", "static"],
                   choices=["dynamic", "masked", "static"], help="SLAM modes to run (default: all three)")
    p.add_argument("--out", required=True, metavar="DIR", help="sweep folder (a rerun into it resumes)")
    p.add_argument("--backend", choices=["local", "ray"], default="local",
                   help="local processes, or Ray tasks (a cluster when RAY_ADDRESS is set; DIR on shared storage)")
    p.add_argument("--jobs", type=int, default=1,
                   help="local: sequences processed at once (each takes about two cores; default 1)")
    p.add_argument("--frames", type=int, default=None, help="frames per sequence")
    p.add_argument("--size", default=None, metavar="WxH", help="image size, e.g. 640x480")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="a scenario field fixed for every run (repeatable)")
    p.add_argument("--slam-set", dest="slam_overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="a SLAM config value fixed for every run (repeatable)")
    p.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("bench", help="performance benchmarks",
                       description="Measure throughput; figures are medians over the frames.")
    p.add_argument("target", choices=["sim"], help="what to benchmark: sim = sequence generation")
    p.add_argument("--frames", type=int, default=30, help="frames per configuration (default 30)")
    p.add_argument("--sizes", nargs="+", default=["640x480", "1242x375"], help="image sizes WxH")
    _add_render_arg(p)
    p.add_argument("--quiet", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"dynaslam2 {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dynaslam2 {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
