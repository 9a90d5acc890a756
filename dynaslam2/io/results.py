"""The results folder of `dynaslam2 run` (DESIGN.md, "Results on disk"): writer and reader.

Per frame, one line is appended to each of
- `poses.txt`    KITTI odometry: the 12 numbers of the estimated 3x4 `T_w_c`, every frame (lost ones too);
- `status.jsonl` one JSON object: frame, state, n_static_matches, n_dynamic_matches, keyframe, extra keys;
- `timing.csv`   `frame,features,stereo,tracking,objects,local_ba,boxes,total` in milliseconds.
With `write_objects` (the `dynamic` mode), per frame also
- `tracks.txt`    KITTI tracking result lines (label_02 columns + score), one per estimated object;
- `objects.jsonl` one JSON object {"frame", "objects": [...]} (see `write_objects`), also for frames
  without objects. It is appended after the frame's tracks.txt lines, so a frame present in
  objects.jsonl has all of its tracks.txt lines.
Each line is flushed as it is written, so a crash keeps every complete frame readable.
`run.json` (written once, atomically, before the first frame) records what made the results: mode, the whole
SLAM config, the sequence's path and `Sequence.fingerprint`, and the package versions.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dynaslam2.classes import KITTI_TYPES
from dynaslam2.errors import InputError
from dynaslam2.io.atomic import AppendLog, write_text_atomic
from dynaslam2.io.kitti import TrackingLabel, format_pose_line, format_tracking_label, object_to_label, read_poses
from dynaslam2.io.types import ObjectEstimate, ObjectState

POSES_FILE = "poses.txt"
STATUS_FILE = "status.jsonl"
TIMING_FILE = "timing.csv"
OBJECTS_FILE = "objects.jsonl"
TRACKS_FILE = "tracks.txt"
METRICS_FILE = "metrics.json"
RUN_FILE = "run.json"
# Every file a run or an eval writes into RES/: `overwrite=True` removes these and nothing else.
RESULT_FILES = (POSES_FILE, STATUS_FILE, TIMING_FILE, OBJECTS_FILE, TRACKS_FILE, METRICS_FILE, RUN_FILE)
# KITTI's value for an orientation (alpha, rotation_y) that was not estimated.
KITTI_UNKNOWN_ANGLE = -10.0

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


def _pose_4x4(value, what: str) -> np.ndarray:
    T = np.asarray(value, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{what} must be a finite 4x4 matrix")
    return T


def estimate_to_label(obj: ObjectEstimate, T_w_c: np.ndarray, frame: int) -> TrackingLabel:
    """KITTI tracking result line of an estimated object (through `kitti.object_to_label`).

    With a 3D box (T_o_b and dims): the box `T_w_o @ T_o_b` with its dims, so location is the box's
    bottom-face centre and rotation_y/alpha its heading, as for GT labels.
    Without a box: location is the estimated object-frame origin itself (centroid of the object's points
    at first observation, moved with the object), in the camera; dims are (0, 0, 0), so the bottom face
    and the centre coincide; rotation_y and alpha are KITTI's "not estimated" -10, because the estimated
    frame's axes are the world axes at first observation, not the vehicle's heading.
    Both: box2d is `obj.box2d` ((-1, -1, -1, -1) when None), truncated 0, occluded 0, score = n_points.
    """
    T_w_b = obj.T_w_b()
    state = ObjectState(
        track_id=obj.track_id, cls=obj.cls, T_w_o=obj.T_w_o if T_w_b is None else T_w_b,
        v_w=obj.v_w, w_w=obj.w_w, dims=(0.0, 0.0, 0.0) if T_w_b is None else tuple(obj.dims),
        truncation=0.0, occlusion=0, box2d=obj.box2d,
    )
    label = object_to_label(state, T_w_c, frame, score=float(obj.n_points))
    if T_w_b is None:
        label = dataclasses.replace(label, alpha=KITTI_UNKNOWN_ANGLE, rotation_y=KITTI_UNKNOWN_ANGLE)
    return label


def _estimate_record(obj: ObjectEstimate, what: str) -> dict:
    if obj.cls not in KITTI_TYPES:
        raise ValueError(f"{what}: class {obj.cls!r} is not one of {sorted(KITTI_TYPES)}")
    has_box = obj.T_o_b is not None and obj.dims is not None
    if has_box != (obj.T_o_b is not None or obj.dims is not None):
        raise ValueError(f"{what}: T_o_b and dims must be given together (or both None)")
    if obj.box2d is not None and len(obj.box2d) != 4:
        raise ValueError(f"{what}: box2d must be (left, top, right, bottom), got {obj.box2d!r}")
    return {
        "track_id": int(obj.track_id),
        "class": obj.cls,
        "T_w_o": _pose_4x4(obj.T_w_o, f"{what}: T_w_o").tolist(),
        "v_w": [float(v) for v in np.asarray(obj.v_w, dtype=float).reshape(3)],
        "w_w": [float(w) for w in np.asarray(obj.w_w, dtype=float).reshape(3)],
        "n_points": int(obj.n_points),
        "instance_id": int(obj.instance_id),
        "box2d": None if obj.box2d is None else [float(b) for b in obj.box2d],
        "T_o_b": _pose_4x4(obj.T_o_b, f"{what}: T_o_b").tolist() if has_box else None,
        "dims": [float(d) for d in obj.dims] if has_box else None,
    }


def _estimate_from_record(record: dict) -> ObjectEstimate:
    box2d, T_o_b, dims = record["box2d"], record["T_o_b"], record["dims"]
    obj = ObjectEstimate(
        track_id=int(record["track_id"]),
        cls=str(record["class"]),
        T_w_o=np.array(record["T_w_o"], dtype=float).reshape(4, 4),
        v_w=np.array(record["v_w"], dtype=float).reshape(3),
        w_w=np.array(record["w_w"], dtype=float).reshape(3),
        n_points=int(record["n_points"]),
        instance_id=int(record["instance_id"]),
        box2d=None if box2d is None else tuple(float(b) for b in np.asarray(box2d, dtype=float).reshape(4)),
        T_o_b=None if T_o_b is None else np.array(T_o_b, dtype=float).reshape(4, 4),
        dims=None if dims is None else tuple(float(d) for d in np.asarray(dims, dtype=float).reshape(3)),
    )
    if obj.cls not in KITTI_TYPES:
        raise ValueError(f"unknown class {obj.cls!r}")
    if not np.all(np.isfinite(obj.T_w_o)):
        raise ValueError("non-finite T_w_o")
    return obj


class ResultsWriter:
    """Appends one frame at a time to the result files of a run folder (frames 0, 1, 2, ... in order)."""

    def __init__(self, out_dir: str | os.PathLike, overwrite: bool = False, run_info: dict | None = None):
        """`run_info`: written to run.json (what made the results) before any frame."""
        self.out_dir = prepare_results_dir(out_dir, overwrite)
        if run_info is not None:
            write_text_atomic(self.out_dir / RUN_FILE, json.dumps(run_info, indent=2, default=_json_default) + "\n")
        self.frames = 0
        self._poses = AppendLog(self.out_dir / POSES_FILE)
        self._status = AppendLog(self.out_dir / STATUS_FILE)
        self._timing = AppendLog(self.out_dir / TIMING_FILE)
        self._timing.write_line(",".join(("frame",) + STAGES))
        self.object_frames = 0
        self._objects: AppendLog | None = None  # objects.jsonl and tracks.txt open at the first write_objects
        self._tracks: AppendLog | None = None

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

    def write_objects(self, index: int, T_w_c: np.ndarray, objects: list[ObjectEstimate]) -> None:
        """Append frame `index` (0, 1, 2, ... in order, every frame, with or without objects) of the
        estimated objects: their KITTI lines to tracks.txt (see `estimate_to_label`), then one line
        {"frame": index, "objects": [{track_id, class, T_w_o, v_w, w_w, n_points, instance_id, box2d,
        T_o_b, dims}]} to objects.jsonl (box2d, T_o_b, dims may be null).

        `T_w_c`: pose of the labels' reference camera at this frame (the left camera for our
        sequences; `T_w_c @ T_left_ref` for real KITTI tracking). The first call creates both files.
        Everything is validated and formatted before any line is written.
        """
        if index != self.object_frames:
            raise ValueError(f"write_objects: expected frame {self.object_frames}, got {index}")
        T_w_c = _pose_4x4(T_w_c, f"write_objects: frame {index}: T_w_c")
        ids = [int(obj.track_id) for obj in objects]
        if len(set(ids)) != len(ids):
            raise ValueError(f"write_objects: frame {index}: duplicate track ids {sorted(ids)}")
        records = [_estimate_record(obj, f"write_objects: frame {index}: track {obj.track_id}") for obj in objects]
        track_lines = [format_tracking_label(estimate_to_label(obj, T_w_c, index)) for obj in objects]
        record_line = json.dumps({"frame": int(index), "objects": records})
        if self._objects is None:
            self._tracks = AppendLog(self.out_dir / TRACKS_FILE)
            self._objects = AppendLog(self.out_dir / OBJECTS_FILE)
        for line in track_lines:
            self._tracks.write_line(line)
        self._objects.write_line(record_line)
        self.object_frames += 1

    def close(self) -> None:
        """Close the files (every written line is already on disk)."""
        for log in (self._poses, self._status, self._timing, self._tracks, self._objects):
            if log is not None:
                log.close()

    def __enter__(self) -> "ResultsWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class Results:
    """A run's results: T_w_c (N, 4, 4), status (N dicts), timing (stage name -> (N,) ms, from timing.csv),
    objects (N lists of ObjectEstimate, from objects.jsonl; empty lists when the run wrote none),
    has_objects (objects.jsonl exists: a `dynamic` run, even one that tracked nothing) and run (run.json, or None
    for results written before it existed)."""

    T_w_c: np.ndarray
    status: list[dict]
    timing: dict[str, np.ndarray]
    objects: list[list[ObjectEstimate]] = field(default_factory=list)
    has_objects: bool = False
    run: dict | None = None

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


def _read_objects(path: Path) -> list[list[ObjectEstimate]]:
    objects = []
    for n, line in enumerate(_complete_lines(path)):
        where = f"{path} line {n + 1}"
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            raise InputError(f"{where}: not valid JSON ({exc.msg})") from None
        if not isinstance(record, dict) or record.get("frame") != n or not isinstance(record.get("objects"), list):
            raise InputError(f"{where}: expected an object with \"frame\": {n} and an \"objects\" list")
        try:
            frame = [_estimate_from_record(r) for r in record["objects"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: invalid object record ({exc!r}); expected keys track_id, class, T_w_o, "
                             "v_w, w_w, n_points, instance_id, box2d, T_o_b, dims") from None
        ids = [obj.track_id for obj in frame]
        if len(set(ids)) != len(ids):
            raise InputError(f"{where}: duplicate track ids {sorted(ids)}")
        objects.append(frame)
    return objects


def read_results(res_dir: str | os.PathLike) -> Results:
    """Read a results folder. A frame counts when all files hold it (poses, status, timing, and
    objects.jsonl when present): a crash between the appends of the last frame leaves a file a line
    ahead, which is dropped; any larger disagreement is an InputError."""
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
    has_objects = (res / OBJECTS_FILE).is_file()
    objects = _read_objects(res / OBJECTS_FILE) if has_objects else []
    if has_objects:
        counts[OBJECTS_FILE] = len(objects)
    n = min(counts.values())
    if max(counts.values()) - n > 1:
        raise InputError(f"results in {res} disagree on the number of frames: "
                         + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return Results(T_w_c=T_w_c[:n], status=status[:n], timing={k: v[:n] for k, v in timing.items()},
                   objects=objects[:n] if has_objects else [[] for _ in range(n)], has_objects=has_objects,
                   run=_read_run(res / RUN_FILE))


def _read_run(path: Path) -> dict | None:
    """run.json, or None where the folder has none; InputError where it is not a JSON object."""
    if not path.is_file():
        return None
    try:
        run = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: unreadable run record ({exc})") from None
    if not isinstance(run, dict):
        raise InputError(f"{path}: expected a JSON object")
    return run
