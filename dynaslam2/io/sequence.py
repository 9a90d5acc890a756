"""Sequences on disk: the writer of our KITTI-compatible layout and a lazy reader for it and real KITTI.

Layout (DESIGN.md, "Sequence on disk"): image_02/ image_03/ depth/ instances/ %06d.png, calib.txt,
label_02.txt, poses.txt, times.txt, objects.jsonl, meta.json. Images are written atomically before the
log lines of their frame, and every log line is flushed whole, so a crash leaves a readable prefix.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import hashlib
import json
import os
import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from dynaslam2.classes import FROM_KITTI_TYPE
from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse
from dynaslam2.io.atomic import AppendLog, write_png_atomic, write_text_atomic
from dynaslam2.io.kitti import (
    TrackingLabel,
    format_pose_line,
    format_tracking_label,
    label_to_object_pose,
    labels_from_lines,
    object_to_label,
    poses_from_lines,
    read_calib,
    read_instance_png,
    read_poses,
    read_times,
    read_tracking_labels,
    reference_to_left,
    stereo_camera_from_calib,
    times_from_lines,
    write_calib,
)
from dynaslam2.io.types import FrameData, ObjectState

FORMAT_NAME = "dynaslam2-sequence"
FORMAT_VERSION = 1
DEPTH_PNG_UNITS_PER_M = 1000.0  # depth PNGs hold millimetres
KITTI_FRAME_PERIOD_S = 0.1  # KITTI records at 10 Hz (used when a sequence has no times.txt)
# What a sequence folder may contain; `--overwrite` removes only these and refuses anything else.
SEQUENCE_DIRS = ("image_02", "image_03", "depth", "instances")
SEQUENCE_FILES = ("calib.txt", "label_02.txt", "poses.txt", "times.txt", "objects.jsonl", "meta.json")
REPLACEABLE_PATTERNS = ("preview*", ".*.tmp")
PNG_WRITER_THREADS = 4  # one per image of a frame (left, right, instances, depth)


def _frame_name(i: int) -> str:
    return f"{i:06d}.png"


# ----------------------------------------------------------------------------------------------
# Writer


def _prepare_output_dir(out_dir: Path, overwrite: bool) -> None:
    """Validate (and with `overwrite` empty) the output folder; raises InputError before writing anything."""
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"output path {out_dir} is a file; expected a folder for the sequence")
    if out_dir.is_dir():
        entries = sorted(out_dir.iterdir())
        if entries and not overwrite:
            raise InputError(f"output folder {out_dir} is not empty; pass --overwrite to replace it")
        unknown = [
            e.name for e in entries
            if not (e.name in SEQUENCE_FILES and e.is_file() or e.name in SEQUENCE_DIRS and e.is_dir()
                    or any(fnmatch.fnmatch(e.name, p) for p in REPLACEABLE_PATTERNS))
        ]
        if unknown:
            raise InputError(
                f"output folder {out_dir} holds files that are not part of a sequence "
                f"({', '.join(unknown[:3])}{', ...' if len(unknown) > 3 else ''}); refusing to overwrite it"
            )
        if not os.access(out_dir, os.W_OK | os.X_OK):
            raise InputError(f"output folder {out_dir} is not writable")
        for e in entries:
            if e.is_dir() and not e.is_symlink():
                shutil.rmtree(e)
            else:
                e.unlink()
        return
    ancestor = out_dir.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise InputError(f"cannot create output folder {out_dir}: {ancestor} is a file")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise InputError(f"cannot create output folder {out_dir}: {ancestor} is not writable")
    try:
        out_dir.mkdir(parents=True)
    except OSError as e:
        raise InputError(f"cannot create output folder {out_dir}: {e.strerror or e}") from None


def _object_record(obj: ObjectState) -> dict:
    record = {
        "track_id": int(obj.track_id),
        "class": obj.cls,
        "T_w_o": np.asarray(obj.T_w_o, dtype=float).tolist(),
        "v_w": np.asarray(obj.v_w, dtype=float).tolist(),
        "w_w": np.asarray(obj.w_w, dtype=float).tolist(),
        "dims": [float(d) for d in obj.dims],
        "visible_fraction": float(obj.visible_fraction),
        "truncation": float(obj.truncation),
        "occlusion": int(obj.occlusion),
        "box2d": None if obj.box2d is None else [float(b) for b in obj.box2d],
    }
    if obj.extra:
        record["extra"] = obj.extra
    return record


def _object_from_record(record: dict) -> ObjectState:
    box2d = record.get("box2d")
    return ObjectState(
        track_id=int(record["track_id"]),
        cls=record["class"],
        T_w_o=np.array(record["T_w_o"], dtype=float),
        v_w=np.array(record["v_w"], dtype=float),
        w_w=np.array(record["w_w"], dtype=float),
        dims=tuple(float(d) for d in record["dims"]),
        visible_fraction=float(record["visible_fraction"]),
        truncation=float(record["truncation"]),
        occlusion=int(record["occlusion"]),
        box2d=None if box2d is None else tuple(float(b) for b in box2d),
        extra=dict(record.get("extra", {})),
    )


class SequenceWriter:
    """Writes a sequence frame by frame in the layout of DESIGN.md.

    The output folder must not exist, be empty, or (with `overwrite=True`) hold only a previous
    sequence's files (SEQUENCE_DIRS, SEQUENCE_FILES, preview*): anything else is refused, so
    `--overwrite` never deletes unrelated data. All checks run before anything is written.
    meta.json is `meta` plus format, format_version, image_size [W, H], with_depth, frames and
    complete (false until `close()`; these keys override same-named keys of `meta`).
    """

    def __init__(self, out_dir, camera: StereoCamera, meta: dict, overwrite: bool = False, with_depth: bool = True):
        self.out_dir = Path(out_dir)
        self.camera = camera
        self.with_depth = bool(with_depth)
        self._meta = dict(meta)
        self._meta.update(
            format=FORMAT_NAME,
            format_version=FORMAT_VERSION,
            image_size=[int(camera.width), int(camera.height)],
            with_depth=self.with_depth,
            complete=False,
            frames=0,
        )
        try:
            meta_text = json.dumps(self._meta, indent=2, sort_keys=True) + "\n"
        except (TypeError, ValueError) as e:
            raise ValueError(f"sequence meta must be JSON-serialisable: {e}") from None
        _prepare_output_dir(self.out_dir, overwrite)
        self.frames_written = 0
        write_calib(self.out_dir / "calib.txt", camera)
        write_text_atomic(self.out_dir / "meta.json", meta_text)
        for d in SEQUENCE_DIRS:
            if d != "depth" or self.with_depth:
                (self.out_dir / d).mkdir()
        self._pool = ThreadPoolExecutor(max_workers=PNG_WRITER_THREADS, thread_name_prefix="png-writer")
        self._logs = {
            name: AppendLog(self.out_dir / name) for name in ("poses.txt", "times.txt", "label_02.txt", "objects.jsonl")
        }

    def _check_image(self, name: str, image, dtype, channels: int | None) -> np.ndarray:
        image = np.asarray(image)
        shape = (self.camera.height, self.camera.width) + ((channels,) if channels else ())
        if image.shape != shape or image.dtype != dtype:
            raise ValueError(f"frame {self.frames_written}: {name} must be {np.dtype(dtype)} {shape}, "
                             f"got {image.dtype} {image.shape}")
        return image

    def write_frame(self, frame: FrameData, T_w_c: np.ndarray, objects: list[ObjectState]) -> None:
        """Write frame `frames_written`: images first (atomically), then one line per log."""
        i = self.frames_written
        if frame.index != i:
            raise ValueError(f"frames must be written in order: expected index {i}, got {frame.index}")
        T_w_c = np.asarray(T_w_c, dtype=float)
        if T_w_c.shape != (4, 4) or not np.all(np.isfinite(T_w_c)):
            raise ValueError(f"frame {i}: T_w_c must be a finite 4x4 matrix")
        left = self._check_image("left", frame.left, np.uint8, 3)
        right = self._check_image("right", frame.right, np.uint8, 3)
        instances = self._check_image("instances", frame.instances, np.uint16, None)
        labels = [format_tracking_label(object_to_label(obj, T_w_c, i)) for obj in objects]
        record = json.dumps({"frame": i, "objects": [_object_record(obj) for obj in objects]})
        name = _frame_name(i)
        images = [(self.out_dir / "image_02" / name, left), (self.out_dir / "image_03" / name, right),
                  (self.out_dir / "instances" / name, instances)]
        if self.with_depth:
            depth = self._check_image("depth", frame.depth, np.float32, None)
            images.append((self.out_dir / "depth" / name, depth_to_png(depth)))
        # PNG encoding releases the GIL: encode the images in parallel, all done before any log line.
        for future in [self._pool.submit(write_png_atomic, path, image) for path, image in images]:
            future.result()
        self._logs["poses.txt"].write_line(format_pose_line(T_w_c))
        self._logs["times.txt"].write_line(f"{float(frame.timestamp):.9e}")
        for line in labels:
            self._logs["label_02.txt"].write_line(line)
        self._logs["objects.jsonl"].write_line(record)
        self.frames_written = i + 1

    def _close_logs(self) -> None:
        self._pool.shutdown(wait=True)
        for log in self._logs.values():
            log.close()

    def close(self) -> None:
        """Close the logs and mark the sequence complete in meta.json."""
        self._close_logs()
        self._meta.update(complete=True, frames=self.frames_written)
        write_text_atomic(self.out_dir / "meta.json", json.dumps(self._meta, indent=2, sort_keys=True) + "\n")

    def __enter__(self) -> "SequenceWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self._close_logs()  # keep what was written; meta.json stays "complete": false


def depth_to_png(depth_m: np.ndarray) -> np.ndarray:
    """float metres -> uint16 millimetres; 0 (no depth) where the depth is 0, non-finite or beyond
    the 65.535 m a uint16 holds (writing 65.535 m there would be silently wrong depth)."""
    depth_m = np.asarray(depth_m, dtype=np.float64)
    mm = np.where(np.isfinite(depth_m) & (depth_m > 0), np.rint(depth_m * DEPTH_PNG_UNITS_PER_M), 0.0)
    return np.where(mm <= 65535, mm, 0).astype(np.uint16)


def depth_from_png(depth_mm: np.ndarray) -> np.ndarray:
    """uint16 millimetres -> float32 metres (0 = none)."""
    return depth_mm.astype(np.float32) / np.float32(DEPTH_PNG_UNITS_PER_M)


# ----------------------------------------------------------------------------------------------
# Reader


def _count_frames(folder: Path) -> int:
    """Number of consecutive frames 000000.png, 000001.png, ... present in `folder`."""
    if not folder.is_dir():
        return 0
    names = {e.name for e in os.scandir(folder)}
    n = 0
    while _frame_name(n) in names:
        n += 1
    return n


def _complete_lines(path: Path) -> list[str]:
    """Newline-terminated lines of a log (a line cut by a crash is dropped); [] if absent."""
    if not path.is_file():
        return []
    text = path.read_text(encoding="utf-8")
    return text.split("\n")[:-1]


def _read_image(path: Path, color: bool) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: cannot read image")
    if image.ndim == 3:
        if image.shape[2] == 4:
            image = image[:, :, :3]
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if color else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image


def _image_size(path: Path) -> tuple[int, int]:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: cannot read image")
    return image.shape[1], image.shape[0]


class Sequence:
    """A stereo sequence on disk, loaded lazily frame by frame.

    kind: "sim" | "kitti_odometry" | "kitti_tracking"; camera: the left camera + baseline;
    timestamps (seconds) and gt_T_w_c ((N, 4, 4) or None) cover the complete frames only.
    """

    def __init__(
        self,
        kind: str,
        path: Path,
        camera: StereoCamera,
        meta: dict,
        timestamps: np.ndarray,
        gt_T_w_c: np.ndarray | None,
        frame_dirs: dict[str, Path],
        n_frames: int,
        color: bool,
        labels: list[TrackingLabel],
        T_left_ref: np.ndarray,
        object_records: list[str] | None = None,
    ):
        self.kind = kind
        self.path = path
        self.camera = camera
        self.meta = meta
        self._n = n_frames
        self.timestamps = timestamps[:n_frames]
        self.gt_T_w_c = None if gt_T_w_c is None else gt_T_w_c[:n_frames]
        self._dirs = frame_dirs
        self._color = color
        self._labels_by_frame: dict[int, list[TrackingLabel]] = {}
        for label in labels:
            if 0 <= label.frame < n_frames:
                self._labels_by_frame.setdefault(label.frame, []).append(label)
        self._T_left_ref = T_left_ref
        self._object_records = object_records

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i: int) -> FrameData:
        if not isinstance(i, (int, np.integer)):
            raise TypeError(f"sequence index must be an integer, got {type(i).__name__}")
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(f"frame {i} out of range for a sequence of {self._n} frames")
        name = _frame_name(int(i))
        depth_dir, inst_dir = self._dirs.get("depth"), self._dirs.get("instances")
        depth = None
        if depth_dir is not None:
            depth_mm = cv2.imread(str(depth_dir / name), cv2.IMREAD_UNCHANGED)
            if depth_mm is None or depth_mm.dtype != np.uint16:
                raise InputError(f"{depth_dir / name}: expected a 16-bit depth PNG")
            depth = depth_from_png(depth_mm)
        instances = read_instance_png(inst_dir / name) if inst_dir is not None and (inst_dir / name).is_file() else None
        return FrameData(
            index=int(i),
            timestamp=float(self.timestamps[i]),
            left=_read_image(self._dirs["left"] / name, self._color),
            right=_read_image(self._dirs["right"] / name, self._color),
            depth=depth,
            instances=instances,
        )

    def __iter__(self):
        for i in range(self._n):
            yield self[i]

    def gt_labels(self, i: int) -> list[TrackingLabel]:
        """KITTI tracking labels of frame i (DontCare included), [] if none."""
        return list(self._labels_by_frame.get(i, []))

    def gt_objects(self, i: int) -> list[ObjectState]:
        """Ground-truth objects of frame i in the world frame (camera frame when there are no GT poses).

        Ours: exact states from objects.jsonl. KITTI tracking: from label_02 (types without one of our
        classes, e.g. DontCare, Misc, Tram, Person, are skipped); velocities, visible fraction and
        truncated fraction are unknown there and set to NaN (the KITTI truncation level is in
        extra["kitti_truncated"]).
        """
        if not 0 <= i < self._n:
            raise IndexError(f"frame {i} out of range for a sequence of {self._n} frames")
        if self._object_records is not None:
            try:
                record = json.loads(self._object_records[i])
                return [_object_from_record(r) for r in record["objects"]]
            except (ValueError, KeyError, TypeError) as e:
                raise InputError(f"{self.path / 'objects.jsonl'}, line {i + 1}: invalid object record ({e!r})") from None
        T_w_c = self.gt_T_w_c[i] if self.gt_T_w_c is not None else np.eye(4)
        T_w_ref = T_w_c @ self._T_left_ref
        objects = []
        for label in self._labels_by_frame.get(i, []):
            if label.type not in FROM_KITTI_TYPE:
                continue
            T_w_o, dims = label_to_object_pose(label, T_w_ref)
            objects.append(ObjectState(
                track_id=label.track_id, cls=FROM_KITTI_TYPE[label.type], T_w_o=T_w_o,
                v_w=np.full(3, np.nan), w_w=np.full(3, np.nan), dims=dims,
                visible_fraction=float("nan"), truncation=float("nan"), occlusion=int(label.occluded),
                box2d=label.box2d, extra={"kitti_truncated": label.truncated},
            ))
        return objects

    def fingerprint(self) -> str:
        """16 hex digits identifying what the sequence's ground truth depends on: its kind, camera, timestamps and,
        for a simulated one, the world version, scenario and seed (not the frames' bytes, not the rendering
        settings). `dynaslam2 run` records it in RES/run.json; `dynaslam2 eval` refuses another sequence's results."""
        sim = {k: self.meta.get(k) for k in ("scenario", "seed")}
        sim["world"] = self.meta.get("versions", {}).get("sim_world")
        head = json.dumps([self.kind, dataclasses.astuple(self.camera), sim], sort_keys=True, default=str)
        digest = hashlib.sha256(head.encode())
        digest.update(np.round(np.asarray(self.timestamps, dtype=np.float64), 6).tobytes())
        return digest.hexdigest()[:16]

    def __repr__(self) -> str:
        c = self.camera
        return f"Sequence({self.kind!r}, {str(self.path)!r}, {self._n} frames, {c.width}x{c.height}, B={c.baseline:.3f} m)"


def _stereo_size(left_dir: Path, right_dir: Path) -> tuple[int, int]:
    """Image size of frame 0, checking that the left and right images agree."""
    left_size = _image_size(left_dir / _frame_name(0))
    right_size = _image_size(right_dir / _frame_name(0))
    if left_size != right_size:
        raise InputError(
            f"{right_dir / _frame_name(0)}: right image is {right_size[0]}x{right_size[1]} but the left image "
            f"{left_dir / _frame_name(0)} is {left_size[0]}x{left_size[1]}; expected a rectified pair of equal size"
        )
    return left_size


def _require_dir(path: Path, what: str) -> Path:
    if not path.is_dir():
        raise InputError(f"{path}: missing {what} folder")
    return path


def _read_meta(path: Path) -> dict:
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read sequence metadata ({e})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path}: expected a JSON object")
    return meta


def _open_sim(path: Path) -> Sequence:
    """Our layout. depth/ and instances/ are optional (meta.json's with_depth makes depth/ required);
    poses.txt, times.txt and objects.jsonl count towards the complete frames when present."""
    meta = _read_meta(path / "meta.json") if (path / "meta.json").is_file() else {}
    left_dir = path / "image_02"
    right_dir = _require_dir(path / "image_03", "right images (image_03/)")
    calib_path = path / "calib.txt"
    calib = read_calib(calib_path)
    dirs = {"left": left_dir, "right": right_dir}
    if meta.get("with_depth", False):
        dirs["depth"] = _require_dir(path / "depth", "depth images (depth/)")
    elif (path / "depth").is_dir():
        dirs["depth"] = path / "depth"
    if (path / "instances").is_dir():
        dirs["instances"] = path / "instances"
    logs = {name: _complete_lines(path / name) for name in ("poses.txt", "times.txt", "objects.jsonl")
            if (path / name).is_file()}
    n = min([_count_frames(d) for d in dirs.values()] + [len(lines) for lines in logs.values()])
    if n > 0:
        width, height = _stereo_size(left_dir, right_dir)
        if "image_size" in meta and list(meta["image_size"]) != [width, height]:
            raise InputError(f"{left_dir / _frame_name(0)}: image is {width}x{height} but {path / 'meta.json'} "
                             f"says {meta['image_size'][0]}x{meta['image_size'][1]}")
    elif "image_size" in meta:
        width, height = (int(v) for v in meta["image_size"])
    else:
        raise InputError(f"{path}: sequence has no complete frame and meta.json gives no image_size")
    camera = stereo_camera_from_calib(calib, width, height, "P2", "P3", source=str(calib_path))
    gt = poses_from_lines(logs["poses.txt"][:n], path / "poses.txt") if "poses.txt" in logs else None
    if "times.txt" in logs:
        times = times_from_lines(logs["times.txt"][:n], path / "times.txt")
    else:
        times = np.arange(n) / float(meta.get("fps", 1.0 / KITTI_FRAME_PERIOD_S))
    labels = labels_from_lines(_complete_lines(path / "label_02.txt"), path / "label_02.txt")
    object_lines = logs["objects.jsonl"][:n] if "objects.jsonl" in logs else None
    return Sequence("sim", path, camera, meta, times, gt, dirs, n, True, labels, np.eye(4), object_lines)


def _open_kitti_odometry(path: Path) -> Sequence:
    """KITTI odometry: grey image_0/ + image_1/ with P0/P1, or (without image_0/) colour image_2/ +
    image_3/ with P2/P3, whose GT poses are moved from cam0 to cam2 (world = cam2 at frame 0)."""
    grey = (path / "image_0").is_dir()
    left_name, right_name, P_left, P_right = ("image_0", "image_1", "P0", "P1") if grey else ("image_2", "image_3", "P2", "P3")
    left_dir = path / left_name
    right_dir = _require_dir(path / right_name, f"right images ({right_name}/)")
    calib_path = path / "calib.txt"
    calib = read_calib(calib_path)
    counts = [_count_frames(left_dir), _count_frames(right_dir)]
    if counts[0] == 0:
        raise InputError(f"{left_dir}: no images 000000.png, 000001.png, ...")
    if counts[1] == 0:
        raise InputError(f"{right_dir}: no right images 000000.png, 000001.png, ...")
    width, height = _stereo_size(left_dir, right_dir)
    camera = stereo_camera_from_calib(calib, width, height, P_left, P_right, source=str(calib_path))
    meta = {"source": "kitti_odometry", "sequence": path.name, "cameras": [left_name, right_name]}
    times = None
    if (path / "times.txt").is_file():
        times = read_times(path / "times.txt")
        counts.append(len(times))
    gt = None
    for poses_path in (path / "poses.txt", path.parent.parent / "poses" / f"{path.name}.txt"):
        if poses_path.is_file():
            gt = read_poses(poses_path)  # T_w_c0, world = cam0 at frame 0
            if not grey:
                T_c2_c0 = reference_to_left(calib, P_left)
                gt = T_c2_c0 @ gt @ inverse(T_c2_c0)
            counts.append(len(gt))
            meta["poses"] = str(poses_path)
            break
    n = min(counts)
    if times is None:
        times = np.arange(n) * KITTI_FRAME_PERIOD_S
        meta["timestamps"] = f"none on disk; {1 / KITTI_FRAME_PERIOD_S:g} Hz assumed"
    dirs = {"left": left_dir, "right": right_dir}
    color = cv2.imread(str(left_dir / _frame_name(0)), cv2.IMREAD_UNCHANGED).ndim == 3
    return Sequence("kitti_odometry", path, camera, meta, times, gt, dirs, n, color, [], np.eye(4))


def _open_kitti_tracking(root: Path, sequence: str) -> Sequence:
    left_dir = _require_dir(root / "image_02" / sequence, f"left images (image_02/{sequence}/)")
    right_dir = _require_dir(root / "image_03" / sequence, f"right images (image_03/{sequence}/)")
    calib_path = root / "calib" / f"{sequence}.txt"
    calib = read_calib(calib_path)
    dirs = {"left": left_dir, "right": right_dir}
    counts = [_count_frames(left_dir), _count_frames(right_dir)]
    if counts[0] == 0 or counts[1] == 0:
        raise InputError(f"{left_dir if counts[0] == 0 else right_dir}: no images 000000.png, 000001.png, ...")
    if (root / "instances" / sequence).is_dir():  # KITTI MOTS instance PNGs
        dirs["instances"] = root / "instances" / sequence
    n = min(counts)
    width, height = _stereo_size(left_dir, right_dir)
    camera = stereo_camera_from_calib(calib, width, height, "P2", "P3", source=str(calib_path))
    labels_path = root / "label_02" / f"{sequence}.txt"
    labels = read_tracking_labels(labels_path) if labels_path.is_file() else []
    times = np.arange(n) * KITTI_FRAME_PERIOD_S
    meta = {"source": "kitti_tracking", "sequence": sequence,
            "timestamps": f"none on disk; {1 / KITTI_FRAME_PERIOD_S:g} Hz assumed"}
    return Sequence("kitti_tracking", root, camera, meta, times, None, dirs, n, True, labels,
                    reference_to_left(calib, "P2"))


def open_sequence(path, sequence: str | None = None) -> Sequence:
    """Open a sequence folder: ours (image_02/ + meta.json or label_02.txt), KITTI odometry
    (image_0/ + image_1/ or image_2/ + image_3/, calib.txt[, times.txt, poses.txt or ../../poses/NN.txt])
    or KITTI tracking (ROOT with image_02/NNNN/ and `sequence="NNNN"`, or a path pointing at
    ROOT/image_02/NNNN; calib/NNNN.txt, optional label_02/NNNN.txt and MOTS instances/NNNN/)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: sequence folder not found")
    if not path.is_dir():
        raise InputError(f"{path}: expected a sequence folder, found a file")
    if path.parent.name == "image_02" and _count_frames(path) > 0:
        return _open_kitti_tracking(path.parent.parent, path.name)
    if sequence is not None:
        return _open_kitti_tracking(path, sequence)
    if (path / "image_02").is_dir() and ((path / "meta.json").is_file() or (path / "label_02.txt").is_file()):
        return _open_sim(path)
    if (path / "image_0").is_dir() or (path / "image_2").is_dir() and (path / "calib.txt").is_file():
        return _open_kitti_odometry(path)
    if (path / "image_02").is_dir() and any(p.is_dir() for p in (path / "image_02").iterdir()):
        found = sorted(p.name for p in (path / "image_02").iterdir() if p.is_dir())
        raise InputError(f"{path}: KITTI tracking folder with sequences {', '.join(found[:5])}; "
                         f"pass the sequence (e.g. {path / 'image_02' / found[0]})")
    raise InputError(
        f"{path}: not a sequence folder; expected image_02/ with meta.json (simulated), image_0/ + image_1/ + "
        "calib.txt (KITTI odometry) or image_02/NNNN/ (KITTI tracking)"
    )
