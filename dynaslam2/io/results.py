"""The results folder of `dynaslam2 run` (DESIGN.md, "Results on disk"): writer and reader.

Per frame, one line is appended to each of
- `poses.txt`    KITTI odometry: the 12 numbers of the estimated 3x4 `T_w_c`, every frame (lost ones too);
- `status.jsonl` one JSON object: frame, state, n_static_matches, n_dynamic_matches, keyframe, extra keys;
- `timing.csv`   `frame,features,stereo,tracking,objects,local_ba,boxes,total` in milliseconds.
Each line is flushed as it is written, so a crash keeps every complete frame readable.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dynaslam2.errors import InputError
from dynaslam2.io.atomic import AppendLog
from dynaslam2.io.kitti import format_pose_line, read_poses

POSES_FILE = "poses.txt"
STATUS_FILE = "status.jsonl"
TIMING_FILE = "timing.csv"
METRICS_FILE = "metrics.json"
# Every file a run or an eval writes into RES/: `overwrite=True` removes these and nothing else.
RESULT_FILES = (POSES_FILE, STATUS_FILE, TIMING_FILE, "objects.jsonl", "tracks.txt", METRICS_FILE)

STAGES = ("features", "stereo", "tracking", "objects", "local_ba", "boxes", "total")
STATES = ("ok", "lost", "relocalized", "new_segment", "init")
STATUS_KEYS = ("state", "n_static_matches", "n_dynamic_matches", "keyframe")


def prepare_results_dir(out_dir: str | os.PathLike, overwrite: bool) -> Path:
    """Create `out_dir` or check it: a non-empty folder needs `overwrite` (its result files are then removed)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"results folder {out} is a file; expected a folder (or a path to create)")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise InputError(f"results folder {out} is not empty; pass --overwrite to replace its results, "
                             "or choose another folder")
        for name in RESULT_FILES:
            (out / name).unlink(missing_ok=True)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create results folder {out}: {exc.strerror}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"results folder {out} is not writable")
    return out


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"status value of type {type(value).__name__} is not JSON serializable")


class ResultsWriter:
    """Appends one frame at a time to the result files of a run folder (frames 0, 1, 2, ... in order)."""

    def __init__(self, out_dir: str | os.PathLike, overwrite: bool = False):
        self.out_dir = prepare_results_dir(out_dir, overwrite)
        self.frames = 0
        self._poses = AppendLog(self.out_dir / POSES_FILE)
        self._status = AppendLog(self.out_dir / STATUS_FILE)
        self._timing = AppendLog(self.out_dir / TIMING_FILE)
        self._timing.write_line(",".join(("frame",) + STAGES))

    def write_frame(self, index: int, T_w_c: np.ndarray, status: dict, timing_ms: dict[str, float]) -> None:
        """Append frame `index`: its estimated `T_w_c` (4x4), status dict and stage timings in ms.

        `status` needs the keys of STATUS_KEYS (state one of STATES); further keys are kept as they are.
        `timing_ms` maps stage names of STAGES to ms; a missing stage is written as 0, a missing
        `total` as the sum of the given stages. All three lines are formatted before any is written.
        """
        if index != self.frames:
            raise ValueError(f"write_frame: expected frame {self.frames}, got {index}")
        T_w_c = np.asarray(T_w_c, dtype=float)
        if T_w_c.shape != (4, 4) or not np.all(np.isfinite(T_w_c)):
            raise ValueError(f"write_frame: frame {index}: T_w_c must be a finite 4x4 matrix")
        missing = [k for k in STATUS_KEYS if k not in status]
        if missing or status["state"] not in STATES:
            raise ValueError(f"write_frame: frame {index}: status needs keys {STATUS_KEYS} with state in {STATES}, "
                             f"got {status!r}")
        unknown = set(timing_ms) - set(STAGES)
        if unknown:
            raise ValueError(f"write_frame: frame {index}: unknown timing stages {sorted(unknown)}; known: {STAGES}")
        times = {s: float(timing_ms.get(s, 0.0)) for s in STAGES}
        if "total" not in timing_ms:
            times["total"] = sum(times[s] for s in STAGES[:-1])
        pose_line = format_pose_line(T_w_c)
        status_line = json.dumps({"frame": int(index), **status}, default=_json_default)
        timing_line = ",".join([str(int(index))] + [f"{times[s]:.3f}" for s in STAGES])
        self._poses.write_line(pose_line)
        self._status.write_line(status_line)
        self._timing.write_line(timing_line)
        self.frames += 1

    def close(self) -> None:
        """Close the files (every written line is already on disk)."""
        for log in (self._poses, self._status, self._timing):
            log.close()

    def __enter__(self) -> "ResultsWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class Results:
    """A run's results: T_w_c (N, 4, 4), status (N dicts), timing (stage name -> (N,) ms, from timing.csv)."""

    T_w_c: np.ndarray
    status: list[dict]
    timing: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.T_w_c)


def _complete_lines(path: Path) -> list[str]:
    """Lines of a text file that end with a newline (a crash can leave the last one cut)."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise InputError(f"missing results file {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read results file {path}: {exc}") from None
    return text.split("\n")[:-1]


def _read_status(path: Path) -> list[dict]:
    status = []
    for n, line in enumerate(_complete_lines(path)):
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            raise InputError(f"{path} line {n + 1}: not valid JSON ({exc.msg})") from None
        if not isinstance(record, dict) or record.get("frame") != n or record.get("state") not in STATES:
            raise InputError(f"{path} line {n + 1}: expected an object with \"frame\": {n} and \"state\" "
                             f"one of {list(STATES)}")
        status.append(record)
    return status


def _read_timing(path: Path) -> dict[str, np.ndarray]:
    lines = _complete_lines(path)
    header = lines[0].split(",") if lines else []
    if not header or header[0] != "frame" or not set(STAGES) <= set(header):
        raise InputError(f"{path}: expected the header {','.join(('frame',) + STAGES)}")
    rows = [line.split(",") for line in lines[1:]]
    bad = next((n for n, row in enumerate(rows) if len(row) != len(header)), None)
    if bad is not None:
        raise InputError(f"{path} line {bad + 2}: expected {len(header)} comma-separated values")
    try:
        table = np.array(rows, dtype=float).reshape(len(rows), len(header))
    except ValueError:
        raise InputError(f"{path}: non-numeric timing values") from None
    if not np.array_equal(table[:, 0], np.arange(len(rows))):
        raise InputError(f"{path}: frame column must count 0, 1, 2, ... in order")
    return {name: table[:, k] for k, name in enumerate(header) if k > 0}


def read_results(res_dir: str | os.PathLike) -> Results:
    """Read a results folder. A frame counts when all three files hold it: a crash between the
    three appends of the last frame leaves one file a line ahead, which is dropped; any larger
    disagreement is an InputError."""
    res = Path(res_dir)
    if not res.is_dir():
        raise InputError(f"results folder {res} does not exist or is not a folder")
    poses_path = res / POSES_FILE
    if not poses_path.is_file():
        raise InputError(f"missing results file {poses_path}")
    T_w_c = read_poses(poses_path)
    status = _read_status(res / STATUS_FILE)
    timing = _read_timing(res / TIMING_FILE)
    counts = {POSES_FILE: len(T_w_c), STATUS_FILE: len(status), TIMING_FILE: len(timing["total"])}
    n = min(counts.values())
    if max(counts.values()) - n > 1:
        raise InputError(f"results in {res} disagree on the number of frames: "
                         + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return Results(T_w_c=T_w_c[:n], status=status[:n], timing={k: v[:n] for k, v in timing.items()})
