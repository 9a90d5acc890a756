"""Preview of a sequence: MP4 and PNG contact sheet of the left images with instance masks tinted and
ground-truth 2D boxes and track ids drawn, so a user can look at what was generated."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from dynaslam2.classes import CLASS_IDS, INSTANCE_CLASS_FACTOR
from dynaslam2.errors import InputError
from dynaslam2.io.atomic import write_png_atomic
from dynaslam2.io.sequence import open_sequence
from dynaslam2.io.types import FrameData, ObjectState

TINT_ALPHA = 0.45  # weight of the instance colour over the image
SHEET_FRAMES = 12  # frames on the contact sheet
SHEET_COLUMNS = 4
SHEET_WIDTH_PX = 1600  # width of the contact sheet


def instance_colours(ids: np.ndarray) -> np.ndarray:
    """Deterministic, well-spread RGB colour per instance id (golden-ratio hue steps)."""
    hue = (np.asarray(ids, dtype=np.int64) * 0.618033988749895) % 1.0
    hsv = np.stack([hue * 180.0, np.full_like(hue, 200.0), np.full_like(hue, 255.0)], -1).astype(np.uint8)
    return cv2.cvtColor(hsv[None], cv2.COLOR_HSV2RGB)[0]


def annotate(frame: FrameData, objects: list[ObjectState]) -> np.ndarray:
    """Left image (RGB) with instance masks tinted and GT boxes, class and track ids drawn."""
    image = frame.left if frame.left.ndim == 3 else cv2.cvtColor(frame.left, cv2.COLOR_GRAY2RGB)
    out = image.copy()
    if frame.instances is not None:
        ids, inverse = np.unique(frame.instances, return_inverse=True)
        lut = instance_colours(ids).astype(np.float32)
        colour = lut[inverse.reshape(frame.instances.shape)]
        mask = frame.instances > 0
        out[mask] = ((1 - TINT_ALPHA) * image[mask] + TINT_ALPHA * colour[mask]).astype(np.uint8)
    for obj in objects:
        if obj.box2d is None:
            continue
        mots = CLASS_IDS.get(obj.cls, 0) * INSTANCE_CLASS_FACTOR + obj.track_id
        c = tuple(int(v) for v in instance_colours(np.array([mots]))[0])
        x0, y0, x1, y1 = (int(round(v)) for v in obj.box2d)
        cv2.rectangle(out, (x0, y0), (x1, y1), c, 1)
        cv2.putText(out, f"{obj.cls[:3]} {obj.track_id}", (x0, max(y0 - 3, 9)), cv2.FONT_HERSHEY_SIMPLEX,
                    0.35, c, 1, cv2.LINE_AA)
    cv2.putText(out, f"{frame.index:06d}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def contact_sheet(images: list[np.ndarray], columns: int = SHEET_COLUMNS, width_px: int = SHEET_WIDTH_PX) -> np.ndarray:
    """Grid of equally sized RGB images scaled to a sheet `width_px` wide."""
    h, w = images[0].shape[:2]
    tile_w = max(1, width_px // columns)
    tile_h = max(1, round(h * tile_w / w))
    rows = -(-len(images) // columns)
    sheet = np.zeros((rows * tile_h, columns * tile_w, 3), np.uint8)
    for k, img in enumerate(images):
        r, c = divmod(k, columns)
        sheet[r * tile_h:(r + 1) * tile_h, c * tile_w:(c + 1) * tile_w] = cv2.resize(
            img, (tile_w, tile_h), interpolation=cv2.INTER_AREA)
    return sheet


def write_preview(seq_dir: Path, progress: bool = True) -> tuple[Path, Path]:
    """Write `preview.mp4` and `preview.png` into the sequence folder; returns their paths."""
    seq_dir = Path(seq_dir)
    seq = open_sequence(seq_dir)
    n = len(seq)
    if n == 0:
        raise InputError(f"{seq_dir}: no complete frame to preview")
    fps = float(seq.meta.get("fps", 10.0))
    sheet_idx = set(np.unique(np.linspace(0, n - 1, min(SHEET_FRAMES, n)).round().astype(int)).tolist())
    mp4 = seq_dir / "preview.mp4"
    tmp = seq_dir / f"preview.{os.getpid()}.tmp.mp4"  # matches the writer's replaceable "preview*"
    W, H = seq.camera.width, seq.camera.height
    video = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (W, H))
    if not video.isOpened():
        raise InputError(f"{mp4}: cannot open an MP4 writer (OpenCV without an mp4v encoder?)")
    tiles = []
    try:
        for i in tqdm(range(n), desc="preview", unit="frame", disable=not progress, leave=False):
            image = annotate(seq[i], seq.gt_objects(i))
            video.write(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            if i in sheet_idx:
                tiles.append(image)
        video.release()
        os.replace(tmp, mp4)
    finally:
        video.release()
        tmp.unlink(missing_ok=True)
    png = seq_dir / "preview.png"
    write_png_atomic(png, contact_sheet(tiles))
    return mp4, png
