"""KITTI formats: calibration, odometry poses/times, tracking labels, MOTS instance PNGs.

Also the one place that converts between our GT object frame (box centre; x forward, y left, z up;
dims (l, w, h)) and KITTI camera-frame labels (bottom-face centre; rotation_y about camera y;
dims (h, w, l)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dynaslam2.classes import KITTI_TYPES
from dynaslam2.errors import InputError
from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.geometry.se3 import inverse
from dynaslam2.io.atomic import write_png_atomic, write_text_atomic
from dynaslam2.io.types import ObjectState

# Calibration entries KITTI files name differently; each group is stored under all of its names.
_CALIB_ALIASES = (("R_rect", "R0_rect"), ("Tr_velo_cam", "Tr_velo_to_cam"), ("Tr_imu_velo", "Tr_imu_to_velo"))
# KITTI tracking truncation levels (0 none, 1 partial, 2 strong) from a truncated fraction:
# level = number of bounds the fraction exceeds.
TRUNCATION_LEVEL_BOUNDS = (0.0, 0.5)
# Largest y/z offset of the right camera, as a fraction of the baseline, still taken as rectified
# (real KITTI tracking P2/P3: 0.5%; the projected row error is fy * offset / Z).
RECTIFIED_MAX_OFFSET_RATIO = 0.01


def _read_text(path: Path, what: str) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: {what} file not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: expected a {what} file, found a folder") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read {what} file ({e})") from None


def _floats(tokens: list[str], path, lineno: int) -> np.ndarray:
    try:
        vals = np.array([float(t) for t in tokens], dtype=float)
    except ValueError:
        raise InputError(f"{path}, line {lineno}: expected numbers, got {' '.join(tokens)[:80]!r}") from None
    if not np.all(np.isfinite(vals)):
        raise InputError(f"{path}, line {lineno}: non-finite number in {' '.join(tokens)[:80]!r}")
    return vals


# ----------------------------------------------------------------------------------------------
# Calibration


def read_calib(path) -> dict[str, np.ndarray]:
    """Parse a KITTI calib file (tracking or odometry), keys with or without colons.

    12 numbers -> 3x4, 9 numbers -> 3x3, else a flat vector. Aliases are filled in both ways
    (R_rect/R0_rect, Tr_velo_cam/Tr_velo_to_cam, Tr_imu_velo/Tr_imu_to_velo).
    """
    path = Path(path)
    calib: dict[str, np.ndarray] = {}
    for lineno, line in enumerate(_read_text(path, "calibration").splitlines(), 1):
        tokens = line.split()
        if not tokens:
            continue
        key = tokens[0]
        if key.endswith(":"):
            key, values = key[:-1], tokens[1:]
        elif ":" in key:
            key, first = key.split(":", 1)
            values = [first] + tokens[1:]
        else:
            values = tokens[1:]
        if not key or not values:
            raise InputError(f"{path}, line {lineno}: expected 'NAME: numbers', got {line.strip()[:80]!r}")
        vals = _floats(values, path, lineno)
        if key.startswith("P") and key[1:].isdigit() or key.startswith("Tr"):
            if vals.size != 12:
                raise InputError(f"{path}, line {lineno}: {key} needs 12 numbers (3x4), got {vals.size}")
        if key in ("R_rect", "R0_rect") and vals.size != 9:
            raise InputError(f"{path}, line {lineno}: {key} needs 9 numbers (3x3), got {vals.size}")
        calib[key] = vals.reshape(3, 4) if vals.size == 12 else vals.reshape(3, 3) if vals.size == 9 else vals
    if not calib:
        raise InputError(f"{path}: empty calibration file")
    for names in _CALIB_ALIASES:
        found = [n for n in names if n in calib]
        for n in names:
            if found and n not in calib:
                calib[n] = calib[found[0]]
    return calib


def _format_numbers(values: np.ndarray) -> str:
    return " ".join(f"{v:.12e}" for v in np.asarray(values, dtype=float).ravel())


def write_calib(path, camera: StereoCamera) -> None:
    """KITTI tracking calib for a rectified rig whose reference frame is the left camera.

    P0 = P2 = K[I|0], P1 = P3 = K[I|(-fx*B, 0, 0)], R0_rect = I, Tr_velo_to_cam = a virtual LiDAR at the
    left camera with LiDAR axes (x forward, y left, z up), Tr_imu_to_velo = I. Every line is
    `NAME: numbers`, names as in the real KITTI tracking calib files under shared/data, so loaders
    that split on ':' read it (read_calib also accepts the colon-less R_rect/Tr_velo_cam variant).
    """
    P_left, P_right = camera.projection_matrices()
    R_cam_velo = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    lines = [
        f"P0: {_format_numbers(P_left)}",
        f"P1: {_format_numbers(P_right)}",
        f"P2: {_format_numbers(P_left)}",
        f"P3: {_format_numbers(P_right)}",
        f"R0_rect: {_format_numbers(np.eye(3))}",
        f"Tr_velo_to_cam: {_format_numbers(np.hstack([R_cam_velo, np.zeros((3, 1))]))}",
        f"Tr_imu_to_velo: {_format_numbers(np.hstack([np.eye(3), np.zeros((3, 1))]))}",
    ]
    write_text_atomic(path, "\n".join(lines) + "\n")


def stereo_camera_from_calib(
    calib: dict,
    width: int,
    height: int,
    left: str = "P2",
    right: str = "P3",
    source: str = "calibration",
    max_offset_ratio: float = RECTIFIED_MAX_OFFSET_RATIO,
) -> StereoCamera:
    """Rectified StereoCamera (left camera + baseline) from two projection matrices of a calib dict.

    Both matrices may carry a common offset from the reference camera (KITTI's P2/P3 do): the baseline
    comes from the camera-centre difference K^-1 (p_right - p_left). Real KITTI P2/P3 place the right
    camera a few mm off the x axis; offsets in y/z up to `max_offset_ratio` x baseline are accepted and
    dropped, larger ones (or differing intrinsics) are rejected as non-rectified.
    """
    for key in (left, right):
        if key not in calib:
            raise InputError(f"{source}: missing projection matrix {key} (found {', '.join(sorted(calib))})")
    P_left = np.asarray(calib[left], dtype=float).reshape(3, 4)
    P_right = np.asarray(calib[right], dtype=float).reshape(3, 4)
    if not (np.all(np.isfinite(P_left)) and np.all(np.isfinite(P_right))):
        raise InputError(f"{source}: non-finite values in {left} or {right}")
    K_left = P_left[:, :3]
    if not (K_left[0, 0] > 0 and K_left[1, 1] > 0 and K_left[2, 2] == 1.0):
        raise InputError(f"{source}: {left} is not of the form K[I|t] with positive focal lengths")
    t_rel = _solve_upper_K(K_left, P_right[:, 3] - P_left[:, 3])  # right-camera offset, metres
    baseline = -t_rel[0]
    if baseline > 0 and np.hypot(t_rel[1], t_rel[2]) > max_offset_ratio * baseline:
        raise InputError(
            f"{source}: {right} is offset by ({t_rel[1]:.4g}, {t_rel[2]:.4g}) m in y/z from {left}, more than "
            f"{max_offset_ratio:g} x baseline; expected a rectified stereo pair"
        )
    # Validate intrinsics (equal, zero skew) and the baseline sign with the ideal matrices.
    P_left_ideal = np.hstack([K_left, np.zeros((3, 1))])
    P_right_ideal = np.hstack([P_right[:, :3], np.array([[-K_left[0, 0] * baseline], [0.0], [0.0]])])
    return StereoCamera.from_projection_matrices(P_left_ideal, P_right_ideal, width, height, source=source)


def reference_to_left(calib: dict, left: str = "P2") -> np.ndarray:
    """T_left_ref (4x4): maps points of the calib's reference frame (KITTI labels) into the left camera.

    KITTI's P2 = K[I|t] projects reference (rectified cam0) points; the cam2 centre sits at -t.
    """
    P_left = np.asarray(calib[left], dtype=float).reshape(3, 4)
    T_left_ref = np.eye(4)
    T_left_ref[:3, 3] = _solve_upper_K(P_left[:, :3], P_left[:, 3])
    return T_left_ref


def _solve_upper_K(K: np.ndarray, p: np.ndarray) -> np.ndarray:
    """K^-1 p for an upper-triangular K with K[2,2] = 1, by back-substitution (exact for p = (a, 0, 0))."""
    tz = p[2]
    ty = (p[1] - K[1, 2] * tz) / K[1, 1]
    tx = (p[0] - K[0, 1] * ty - K[0, 2] * tz) / K[0, 0]
    return np.array([tx, ty, tz])


# ----------------------------------------------------------------------------------------------
# Odometry poses and timestamps


def _numeric_rows(lines: list[str], source, ncols: int) -> np.ndarray:
    """(N, ncols) floats from text lines (blank lines skipped); errors name `source` and the line."""
    rows = []
    for lineno, line in enumerate(lines, 1):
        tokens = line.split()
        if not tokens:
            continue
        if len(tokens) != ncols:
            raise InputError(f"{source}, line {lineno}: expected {ncols} numbers per line, got {len(tokens)}")
        rows.append(_floats(tokens, source, lineno))
    return np.array(rows, dtype=float).reshape(-1, ncols)


def poses_from_lines(lines: list[str], source="poses") -> np.ndarray:
    """KITTI odometry pose lines (12 numbers, row-major 3x4 T_w_c) -> (N, 4, 4)."""
    rows = _numeric_rows(lines, source, 12)
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :] = rows.reshape(-1, 3, 4)
    return T


def read_poses(path) -> np.ndarray:
    """KITTI odometry poses file -> (N, 4, 4) T_w_c."""
    path = Path(path)
    return poses_from_lines(_read_text(path, "poses").splitlines(), path)


def format_pose_line(T) -> str:
    """One KITTI odometry line: the top 3x4 rows of a 4x4 pose, row-major, %.9e."""
    T = np.asarray(T, dtype=float)
    if T.shape not in ((4, 4), (3, 4)):
        raise ValueError(f"pose must be 4x4 or 3x4, got shape {T.shape}")
    return " ".join(f"{v:.9e}" for v in T[:3, :].ravel())


def write_poses(path, T_array) -> None:
    """Write (N, 4, 4) poses as a KITTI odometry file (atomically)."""
    T_array = np.asarray(T_array, dtype=float).reshape(-1, *np.shape(T_array)[-2:])
    write_text_atomic(path, "".join(format_pose_line(T) + "\n" for T in T_array))


def times_from_lines(lines: list[str], source="timestamps") -> np.ndarray:
    """One timestamp in seconds per line -> (N,)."""
    return _numeric_rows(lines, source, 1)[:, 0]


def read_times(path) -> np.ndarray:
    """KITTI times.txt -> (N,) seconds."""
    path = Path(path)
    return times_from_lines(_read_text(path, "timestamps").splitlines(), path)


# ----------------------------------------------------------------------------------------------
# Tracking labels


@dataclass
class TrackingLabel:
    """One line of a KITTI tracking label (or result) file.

    truncated: KITTI tracking level 0/1/2 (-1 for DontCare); occluded: 0..3 (-1 for DontCare);
    box2d: (left, top, right, bottom) px; dims_hwl: (h, w, l) m; location: bottom-face centre (x, y, z)
    in the rectified reference camera; rotation_y: rad about camera y; score: results only.
    """

    frame: int
    track_id: int
    type: str
    truncated: float
    occluded: int
    alpha: float
    box2d: tuple[float, float, float, float]
    dims_hwl: tuple[float, float, float]
    location: tuple[float, float, float]
    rotation_y: float
    score: float | None = None


def _check_label_tokens(tokens: list[str], path, lineno: int) -> None:
    """Raise the InputError that describes what is wrong with one label line."""
    if len(tokens) not in (17, 18):
        raise InputError(f"{path}, line {lineno}: expected 17 columns (18 with score), got {len(tokens)}")
    try:
        int(tokens[0]), int(tokens[1])
    except ValueError:
        raise InputError(f"{path}, line {lineno}: frame and track id must be integers") from None
    _floats(tokens[3:], path, lineno)


def labels_from_lines(lines: list[str], source="tracking labels") -> list[TrackingLabel]:
    """KITTI tracking label lines (blank lines skipped) -> labels."""
    numbered = [(lineno, line.split()) for lineno, line in enumerate(lines, 1) if line.strip()]
    if not numbered:
        return []
    rows = [tokens for _, tokens in numbered]
    try:
        if any(len(r) not in (17, 18) for r in rows):
            raise ValueError
        ids_list = [(int(r[0]), int(r[1])) for r in rows]
        values_list = [list(map(float, r[3:17])) for r in rows]
        scores = [float(r[17]) if len(r) == 18 else None for r in rows]
        if not np.all(np.isfinite(values_list)) or not all(s is None or math.isfinite(s) for s in scores):
            raise ValueError
    except ValueError:
        for lineno, tokens in numbered:
            _check_label_tokens(tokens, source, lineno)
        raise
    return [
        TrackingLabel(
            frame=i[0],
            track_id=i[1],
            type=r[2],
            truncated=v[0],
            occluded=int(v[1]),
            alpha=v[2],
            box2d=tuple(v[3:7]),
            dims_hwl=tuple(v[7:10]),
            location=tuple(v[10:13]),
            rotation_y=v[13],
            score=sc,
        )
        for r, i, v, sc in zip(rows, ids_list, values_list, scores)
    ]


def read_tracking_labels(path) -> list[TrackingLabel]:
    """All labels of a KITTI tracking label_02 file (or a result file with a score column)."""
    path = Path(path)
    return labels_from_lines(_read_text(path, "tracking labels").splitlines(), path)


_LABEL_NUMBERS_FORMAT = " ".join(["%.6f"] * 12)  # alpha, box2d (4), dims (3), location (3), rotation_y


def _fmt_level(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:.2f}"


def format_tracking_label(label: TrackingLabel) -> str:
    """One KITTI tracking line, numbers as KITTI writes them (%.6f; integer levels as integers)."""
    nums = (label.alpha, *label.box2d, *label.dims_hwl, *label.location, label.rotation_y)
    line = (
        f"{label.frame} {label.track_id} {label.type} {_fmt_level(label.truncated)} {int(label.occluded)} "
        + _LABEL_NUMBERS_FORMAT % nums
    )
    return line if label.score is None else f"{line} {label.score:.6f}"


def _wrap_angle(a: float) -> float:
    return float((a + math.pi) % (2.0 * math.pi) - math.pi)


def truncation_level(fraction: float) -> int:
    """KITTI tracking truncation level (0, 1, 2) of a truncated fraction in [0, 1]."""
    return int(sum(fraction > b for b in TRUNCATION_LEVEL_BOUNDS))


def object_to_label(
    obj: ObjectState, T_w_c: np.ndarray, frame: int, score: float | None = None
) -> TrackingLabel:
    """Our object (T_w_o at the box centre, x fwd, y left, z up, dims l,w,h) -> KITTI camera-frame label.

    location = box centre + (0, h/2, 0) in the camera (KITTI bottom-face centre for upright boxes);
    rotation_y from the object's heading projected on the camera x-z plane (KITTI heading in the
    camera is (cos ry, 0, -sin ry)); alpha = ry - atan2(x, z) wrapped to [-pi, pi).
    box2d is `obj.box2d` or (-1, -1, -1, -1) when unknown.
    """
    if obj.cls not in KITTI_TYPES:
        raise ValueError(f"object {obj.track_id}: class {obj.cls!r} has no KITTI type")
    T_c_o = inverse(np.asarray(T_w_c, dtype=float)) @ np.asarray(obj.T_w_o, dtype=float)
    heading_c = T_c_o[:3, 0]
    centre_c = T_c_o[:3, 3]
    length, width, height = (float(d) for d in obj.dims)
    location = centre_c + np.array([0.0, height / 2.0, 0.0])
    rotation_y = _wrap_angle(math.atan2(-heading_c[2], heading_c[0]))
    alpha = _wrap_angle(rotation_y - math.atan2(location[0], location[2]))
    box2d = tuple(float(b) for b in obj.box2d) if obj.box2d is not None else (-1.0, -1.0, -1.0, -1.0)
    return TrackingLabel(
        frame=int(frame),
        track_id=int(obj.track_id),
        type=KITTI_TYPES[obj.cls],
        truncated=truncation_level(obj.truncation),
        occluded=int(obj.occlusion),
        alpha=alpha,
        box2d=box2d,
        dims_hwl=(height, width, length),
        location=tuple(float(x) for x in location),
        rotation_y=rotation_y,
        score=score,
    )


def label_to_object_pose(label: TrackingLabel, T_w_c: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Inverse of `object_to_label`: (T_w_o of the upright box centre, dims (l, w, h))."""
    height, width, length = label.dims_hwl
    c, s = math.cos(label.rotation_y), math.sin(label.rotation_y)
    T_c_o = np.eye(4)
    T_c_o[:3, 0] = (c, 0.0, -s)  # forward
    T_c_o[:3, 1] = (s, 0.0, c)  # left = up x forward
    T_c_o[:3, 2] = (0.0, -1.0, 0.0)  # up = -y of the camera
    T_c_o[:3, 3] = np.asarray(label.location, dtype=float) - np.array([0.0, height / 2.0, 0.0])
    return np.asarray(T_w_c, dtype=float) @ T_c_o, (float(length), float(width), float(height))


def labels_box_corners(labels: list[TrackingLabel]) -> np.ndarray:
    """(N, 8, 3) corners of the labels' 3D boxes in the camera frame (KITTI devkit order)."""
    hwl = np.array([label.dims_hwl for label in labels], dtype=float).reshape(-1, 3)
    loc = np.array([label.location for label in labels], dtype=float).reshape(-1, 3)
    ry = np.array([label.rotation_y for label in labels], dtype=float)
    x = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * (hwl[:, 2:3] / 2.0)
    y = np.array([0, 0, 0, 0, -1, -1, -1, -1]) * hwl[:, 0:1]
    z = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * (hwl[:, 1:2] / 2.0)
    c, s = np.cos(ry)[:, None], np.sin(ry)[:, None]
    return np.stack([c * x + s * z, y, -s * x + c * z], axis=-1) + loc[:, None, :]


def label_box_corners(label: TrackingLabel) -> np.ndarray:
    """(8, 3) corners of one label's 3D box in the camera frame."""
    return labels_box_corners([label])[0]


# ----------------------------------------------------------------------------------------------
# MOTS instance PNGs


def read_instance_png(path) -> np.ndarray:
    """KITTI MOTS instance PNG (16-bit, class_id*1000 + instance_id) -> uint16 HxW."""
    path = Path(path)
    ids = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if ids is None:
        raise InputError(f"{path}: cannot read instance PNG")
    if ids.dtype != np.uint16 or ids.ndim != 2:
        raise InputError(f"{path}: expected a 16-bit single-channel instance PNG, got {ids.dtype} {ids.shape}")
    return ids


def write_instance_png(path, ids: np.ndarray) -> None:
    """Write uint16 MOTS ids as a 16-bit PNG (atomically)."""
    ids = np.asarray(ids)
    if ids.dtype != np.uint16 or ids.ndim != 2:
        raise ValueError(f"instance ids must be uint16 HxW, got {ids.dtype} {ids.shape}")
    write_png_atomic(path, ids)
