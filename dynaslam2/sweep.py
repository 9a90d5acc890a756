"""`dynaslam2 sweep`: a grid of simulated scenarios x seeds x SLAM modes, run in parallel, scored and tabulated.

A sweep is the researcher's ablation (object speed, occlusion, a SLAM setting) over seeds: every grid point of
scenario fields (`--grid object_speed=0.5,1,2`) and of SLAM config keys (`--grid slam.objects.ba=true,false`) is
simulated for seeds 0..N-1 and run in each mode, and each run is scored by `dynaslam2 eval`'s metrics.

Work unit ("job"): one scenario grid point and seed: its sequence is simulated once, then every SLAM grid point
and mode runs on it and is scored. Jobs run in parallel on `local` processes (spawned, so no MuJoCo/EGL state is
inherited) or as `ray` tasks (a Ray cluster when RAY_ADDRESS is set; DIR must then be storage every node sees).

DIR layout (everything written atomically, so an interrupted sweep keeps every finished run):
    sweep.json                     the sweep's definition; a rerun into DIR must repeat it (then it resumes)
    seq/<point>_s<seed>/           the simulated sequence (DESIGN.md's sequence folder)
    res/<point>_s<seed>/<mode>[_<slam point>]/   `dynaslam2 run`'s results folder with metrics.json
    summary.csv                    one row per run: grid values, seed, mode, status, and the metrics
A rerun skips the runs whose metrics.json exists (the same seed gives the same sequence and estimates).
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import os
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

from dynaslam2.config import load_config
from dynaslam2.errors import InputError
from dynaslam2.io.atomic import write_text_atomic

MODES = ("dynamic", "masked", "static")
SLAM_PREFIX = "slam."
SWEEP_FILE = "sweep.json"
SUMMARY_FILE = "summary.csv"
# The metrics of summary.csv (eval's keys; objects.* empty for masked and static).
SUMMARY_METRICS = ("ego.ate_rmse_m", "ego.rpe_t_m_per_frame", "ego.rpe_r_deg_per_frame", "ego.lost_frames",
                   "objects.ate_rmse_m", "objects.tp_ratio", "objects.gt_tracks", "objects.id_switches",
                   "objects.short_gaps", "objects.short_gaps_kept", "timing.fps")


@dataclass(frozen=True)
class SweepSpec:
    """What a sweep runs: `grid` maps each key (scenario field, or `slam.` + SLAM config key) to its values (strings
    as typed); `sim_overrides` / `slam_overrides` are fixed `key=value`s for every run."""

    scenario: str
    grid: dict[str, list[str]]
    seeds: int
    modes: list[str]
    sim_overrides: list[str]
    slam_overrides: list[str]


@dataclass(frozen=True)
class SlamPoint:
    """One point of the SLAM grid: its folder suffix, its config overrides and its grid values."""

    suffix: str
    overrides: list[str]
    values: dict[str, str]


@dataclass(frozen=True)
class Job:
    """One scenario grid point and seed, with every SLAM grid point and mode to run on its sequence."""

    name: str  # <scenario>[_<point>]_s<seed>
    scenario: str
    seed: int
    sim_overrides: list[str]  # the seed is `seed`
    values: dict[str, str]  # the scenario grid values of this job
    slam_points: list[SlamPoint]
    modes: list[str]


def parse_grid(items: list[str]) -> dict[str, list[str]]:
    """`["object_speed=0.5,1", "slam.objects.ba=true,false"]` -> {key: [values]}; InputError on a malformed item."""
    grid: dict[str, list[str]] = {}
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        vals = [v.strip() for v in values.split(",") if v.strip()]
        if not sep or not key or not vals:
            raise InputError(f"--grid {item!r}: expected key=v1,v2,...")
        if key in grid:
            raise InputError(f"--grid {key}: given twice")
        grid[key] = vals
    return grid


def _slug(assignments: list[tuple[str, str]]) -> str:
    """A folder-name-safe tag of key=value assignments ('' for none)."""
    text = "_".join(f"{k.removeprefix(SLAM_PREFIX)}={v}" for k, v in assignments)
    return "".join(c if c.isalnum() or c in "=.-_" else "-" for c in text)


def _points(grid: dict[str, list[str]]) -> list[list[tuple[str, str]]]:
    """The cartesian product of a grid as lists of (key, value), in the grid's key order."""
    keys = list(grid)
    return [list(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]


def plan(spec: SweepSpec) -> list[Job]:
    """The sweep's jobs; every scenario and SLAM grid point is validated first (one InputError naming the bad key or
    value, before anything runs)."""
    from sim.scenarios import load_scenario

    if spec.seeds < 1:
        raise InputError(f"--seeds: expected a number of seeds >= 1, got {spec.seeds}")
    bad = [m for m in spec.modes if m not in MODES]
    if bad or not spec.modes:
        raise InputError(f"--modes: expected some of {', '.join(MODES)}, got {', '.join(spec.modes) or 'none'}")
    sim_grid = {k: v for k, v in spec.grid.items() if not k.startswith(SLAM_PREFIX)}
    slam_grid = {k: v for k, v in spec.grid.items() if k.startswith(SLAM_PREFIX)}
    if "seed" in sim_grid:
        raise InputError("--grid seed: use --seeds N (seeds 0..N-1)")
    if any(k.removeprefix(SLAM_PREFIX) == "mode" for k in slam_grid):
        raise InputError("--grid slam.mode: use --modes")
    slam_points = []
    for point in _points(slam_grid):
        overrides = spec.slam_overrides + [f"{k.removeprefix(SLAM_PREFIX)}={v}" for k, v in point]
        load_config(None, overrides)
        slam_points.append(SlamPoint(_slug(point), overrides, dict(point)))
    scenario_tag = "".join(c if c.isalnum() or c in ".-_" else "-" for c in Path(spec.scenario).stem)
    jobs = []
    for point in _points(sim_grid):
        overrides = spec.sim_overrides + [f"{k}={v}" for k, v in point]
        load_scenario(spec.scenario, overrides)
        tag = "_".join(filter(None, [scenario_tag, _slug(point)]))
        jobs += [Job(f"{tag}_s{seed}", spec.scenario, seed, overrides, dict(point), slam_points, list(spec.modes))
                 for seed in range(spec.seeds)]
    return jobs


def _run_dir(out: Path, job: Job, mode: str, slam_suffix: str) -> Path:
    return out / "res" / job.name / "_".join(filter(None, [mode, slam_suffix]))


def run_job(job: Job, out: str) -> list[dict]:
    """Simulate the job's sequence (unless complete in DIR) and run, score and record each SLAM point and mode whose
    metrics.json is missing; returns one row per run (a failed run's row carries its error, the others go on)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from dynaslam2.eval.report import evaluate, write_metrics
    from dynaslam2.io.results import METRICS_FILE
    from dynaslam2.runner import run_sequence
    from sim.generate import generate_sequence
    from sim.scenarios import load_scenario

    root = Path(out)
    seq = root / "seq" / job.name
    rows = []
    try:
        meta = seq / "meta.json"
        if not (meta.is_file() and json.loads(meta.read_text()).get("complete")):
            generate_sequence(load_scenario(job.scenario, [*job.sim_overrides, f"seed={job.seed}"]), seq,
                              overwrite=True, progress=False)
        sim_error = None
    except Exception as exc:  # noqa: BLE001 - recorded in the summary, the sweep goes on
        sim_error = _error_line(exc)
    for point, mode in itertools.product(job.slam_points, job.modes):
        row = {"job": job.name, **job.values, **point.values, "seed": job.seed, "mode": mode}
        res = _run_dir(root, job, mode, point.suffix)
        try:
            if sim_error:
                raise RuntimeError(f"simulation failed: {sim_error}")
            if not (res / METRICS_FILE).is_file():
                run_sequence(seq, mode, res, overrides=point.overrides, overwrite=True, progress=False)
                write_metrics(res / METRICS_FILE, evaluate(seq, res))
            row.update(status="ok", **_summary_metrics(json.loads((res / METRICS_FILE).read_text())))
        except Exception as exc:  # noqa: BLE001 - recorded in the summary, the sweep goes on
            row.update(status=f"failed: {_error_line(exc)}")
        rows.append(row)
    return rows


def _error_line(exc: BaseException) -> str:
    if isinstance(exc, InputError):
        return str(exc)
    frame = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    where = f" ({Path(frame.filename).name}:{frame.lineno})" if frame else ""
    return f"{type(exc).__name__}: {exc}{where}".replace("\n", " ")


def _summary_metrics(metrics: dict) -> dict:
    values = {}
    for key in SUMMARY_METRICS:
        node = metrics
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        values[key] = "" if node is None else node
    return values


def _check_definition(out: Path, spec: SweepSpec) -> None:
    """Write sweep.json, or check that DIR's matches `spec` (a rerun resumes only the same sweep)."""
    path = out / SWEEP_FILE
    definition = asdict(spec)
    if path.is_file():
        try:
            previous = json.loads(path.read_text())
        except ValueError:
            raise InputError(f"{path}: not a sweep definition (JSON)") from None
        if previous != json.loads(json.dumps(definition)):
            raise InputError(f"{out} holds another sweep ({path} differs); choose another --out to run this one")
        return
    if out.exists() and any(out.iterdir()):
        raise InputError(f"{out} is not empty and holds no {SWEEP_FILE}; choose an empty or new folder")
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(definition, indent=2) + "\n")


def write_summary(path: Path, spec: SweepSpec, rows: list[dict]) -> None:
    """summary.csv, rows in the sweep's job and run order, atomically."""
    columns = ["job", *spec.grid, "seed", "mode", "status", *SUMMARY_METRICS]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, buf.getvalue())


def run_sweep(spec: SweepSpec, out: str | os.PathLike, backend: str = "local", jobs: int = 1,
              progress: bool = True) -> list[dict]:
    """Plan, run on `backend` ("local": `jobs` spawned processes; "ray": Ray tasks), and write summary.csv after each
    finished job; returns the rows. InputError before anything runs on a bad grid, mode, backend or DIR."""
    from tqdm import tqdm

    if backend not in ("local", "ray"):
        raise InputError(f"--backend: expected local or ray, got {backend!r}")
    if jobs < 1:
        raise InputError(f"--jobs: expected >= 1, got {jobs}")
    planned = plan(spec)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: a file; expected a folder")
    _check_definition(out, spec)
    done: dict[str, list[dict]] = {}
    bar = tqdm(total=len(planned), desc="sweep", unit="job", disable=not progress)

    def finished(job: Job, rows: list[dict]) -> None:
        done[job.name] = rows
        write_summary(out / SUMMARY_FILE, spec, [r for j in planned if j.name in done for r in done[j.name]])
        bar.update(1)

    try:
        if backend == "ray":
            _run_ray(planned, str(out), finished)
        elif jobs == 1:
            for job in planned:
                finished(job, run_job(job, str(out)))
        else:
            _run_local(planned, str(out), jobs, finished)
    finally:
        bar.close()
    return [r for j in planned for r in done.get(j.name, [])]


def format_summary(spec: SweepSpec, rows: list[dict]) -> str:
    """Per grid point and mode, over its seeds: runs ok / all, mean ego ATE, mean object ATE and TP ratio."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((*(row.get(k) for k in spec.grid), row["mode"]), []).append(row)
    head = [*spec.grid, "mode", "ok", "ego ATE m", "obj ATE m", "obj TP"]

    def mean(ok: list[dict], metric: str) -> str:
        vals = [float(r[metric]) for r in ok if r.get(metric) not in ("", None)]
        return f"{sum(vals) / len(vals):.4f}" if vals else "-"

    lines = []
    for key, group in groups.items():
        ok = [r for r in group if r["status"] == "ok"]
        lines.append([*map(str, key), f"{len(ok)}/{len(group)}",
                      *(mean(ok, m) for m in ("ego.ate_rmse_m", "objects.ate_rmse_m", "objects.tp_ratio"))])
    widths = [max(len(str(c)) for c in col) for col in zip(head, *lines)]
    return "\n".join("  ".join(f"{c:>{w}}" for c, w in zip(line, widths)) for line in [head, *lines])


def _run_local(planned: list[Job], out: str, jobs: int, finished) -> None:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # spawn: a forked child would inherit the parent's threads and any GL state (MuJoCo renders through EGL).
    with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(run_job, job, out): job for job in planned}
        for future in as_completed(futures):
            finished(futures[future], future.result())


def _run_ray(planned: list[Job], out: str, finished) -> None:
    try:
        import ray
    except ImportError:
        raise InputError("--backend ray needs Ray: pip install 'ray>=2.9' (or use --backend local)") from None
    if not ray.is_initialized():
        ray.init(address=os.environ.get("RAY_ADDRESS"), log_to_driver=False)
    # Each job runs one SLAM process and its ORB worker process: two CPUs.
    remote = ray.remote(num_cpus=2)(run_job)
    pending = {remote.remote(job, out): job for job in planned}
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            finished(pending.pop(ref), ray.get(ref))
