"""Stereo rendering of the street world: left/right RGB, left metric depth, instance ids, amodal pixel counts.

Passes per frame (each output renders only what it needs):
- left colour pass: RGB;
- left segmentation pass: geom ids AND the depth buffer, read from the same pass (metric z along the
  optical axis, 0 where no geom was hit);
- amodal passes: the geoms of the visible actors are moved to a spare geom group and only that group
  is rendered, at full resolution. Actors whose (conservative) projected boxes do not overlap share
  one pass (greedy colouring of the overlap graph), so an actor's pixels in its pass are exactly its
  amodal mask inside the image, with no resolution error;
- right colour pass: RGB only.

The OpenGL context is created lazily on the first render: a parent process that owns an EGL context
hangs forked workers (gymnasium's AsyncVectorEnv), so building a renderer must not create one.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402  (MUJOCO_GL must be set before the import)

from dynaslam2.classes import CLASS_IDS, INSTANCE_CLASS_FACTOR  # noqa: E402
from sim.groundtruth import box_corners_from_aabb, project_box_rects  # noqa: E402

_GEOM = int(mujoco.mjtObj.mjOBJ_GEOM)
_NGROUP = 6  # mjNGROUP: geom groups 0..5


@dataclass(frozen=True)
class RenderConfig:
    """Rendering quality knobs.

    msaa_samples: multisample anti-aliasing of the colour passes (MuJoCo's `offsamples`). 0 halves the
      render time on the CPU rasterizer; textures stay mip-mapped, only geometry edges alias.
    box_near_m: near plane (m) used to clip actor boxes when projecting them to decide which actors
      share an amodal pass.
    """

    msaa_samples: int = 0
    box_near_m: float = 0.05


@dataclass
class RenderedFrame:
    """The images of one frame and the per-actor pixel statistics the ground truth needs.

    left/right: HxWx3 uint8 RGB (right is None when not rendered); depth: HxW float32 metres along z,
    0 = no geom hit (None when depth is off); instances: HxW uint16 MOTS ids; visible_px: (N,) visible
    pixel count per actor (in `world.actors` order); amodal_px: (N,) pixel count of the actor alone in
    the image (measured only for visible actors, 0 elsewhere); box2d: (N, 4) visible-mask box
    (left, top, right, bottom) in inclusive pixel indices, NaN for actors with no visible pixel.
    timings_ms: render time per pass.
    """

    left: np.ndarray
    right: np.ndarray | None
    depth: np.ndarray | None
    instances: np.ndarray
    visible_px: np.ndarray
    amodal_px: np.ndarray
    box2d: np.ndarray
    timings_ms: dict[str, float] = field(default_factory=dict)


def mots_ids(actors) -> np.ndarray:
    """KITTI MOTS id (`class_id*1000 + track_id`) per actor."""
    ids = np.array([CLASS_IDS[a.cls] * INSTANCE_CLASS_FACTOR + int(a.track_id) for a in actors], dtype=np.int64)
    bad = [a.track_id for a in actors if not 0 < int(a.track_id) < INSTANCE_CLASS_FACTOR]
    if bad:
        raise ValueError(f"actor track ids must lie in 1..{INSTANCE_CLASS_FACTOR - 1} for MOTS ids, got {bad}")
    return ids


def label_stats(labels: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel count and inclusive bounding box (left, top, right, bottom) per label 1..n of an HxW label image.

    Returns counts (n,) and boxes (n, 4) float (NaN where a label has no pixel). Vectorized: one
    bincount over (label, row) and one over (label, column).
    """
    H, W = labels.shape
    lab = labels.astype(np.intp, copy=False)
    rows = np.bincount((lab * H + np.arange(H)[:, None]).ravel(), minlength=(n + 1) * H).reshape(n + 1, H)[1:]
    cols = np.bincount((lab * W + np.arange(W)[None, :]).ravel(), minlength=(n + 1) * W).reshape(n + 1, W)[1:]
    counts = rows.sum(axis=1)
    has_r, has_c = rows > 0, cols > 0
    boxes = np.stack(
        [has_c.argmax(1), has_r.argmax(1), W - 1 - has_c[:, ::-1].argmax(1), H - 1 - has_r[:, ::-1].argmax(1)], 1
    ).astype(float)
    boxes[counts == 0] = np.nan
    return counts, boxes


def share_passes(rects: np.ndarray) -> list[np.ndarray]:
    """Greedy colouring: split actors into groups whose 2D rects (u0, v0, u1, v1) do not overlap.

    Returns a list of index arrays; actors within one group can be rendered in one amodal pass.
    """
    n = len(rects)
    if n == 0:
        return []
    overlap = (
        (rects[:, None, 0] <= rects[None, :, 2]) & (rects[None, :, 0] <= rects[:, None, 2])
        & (rects[:, None, 1] <= rects[None, :, 3]) & (rects[None, :, 1] <= rects[:, None, 3])
    )
    colour = np.full(n, -1)
    for i in range(n):  # over actors (a few dozen), not pixels
        taken = set(colour[overlap[i] & (colour >= 0)].tolist())
        colour[i] = next(c for c in range(n) if c not in taken)
    return [np.flatnonzero(colour == c) for c in range(colour.max() + 1)]


class StereoRenderer:
    """Renders a `sim.world.World` from its left/right cameras. Use as a context manager or call close().

    The world's model gets `offwidth/offheight` raised to the image size and `offsamples` set from
    `RenderConfig.msaa_samples` before the (lazy) GL context is made.
    """

    def __init__(self, world, width: int, height: int, config: RenderConfig = RenderConfig()):
        self.world = world
        self.width, self.height = int(width), int(height)
        self.config = config
        model = world.model
        self._actors = list(world.actors)
        n = len(self._actors)
        self._mots = mots_ids(self._actors)
        # geom id -> actor label (1..N, 0 = not an actor) through the geom's root body.
        body_label = np.zeros(model.nbody, dtype=np.int64)
        body_label[[a.body_id for a in self._actors]] = np.arange(1, n + 1)
        self._geom_label = body_label[model.body_rootid[model.geom_bodyid]]
        self._actor_geoms = [np.flatnonzero(self._geom_label == k + 1) for k in range(n)]
        missing = [a.track_id for a, g in zip(self._actors, self._actor_geoms) if len(g) == 0]
        if missing:
            raise ValueError(f"actors without geoms under their root body: track ids {missing}")
        used = set(np.unique(model.geom_group).tolist())
        spare = [g for g in range(_NGROUP - 1, -1, -1) if g not in used]
        if not spare:
            raise ValueError("no spare geom group left for amodal rendering (all 6 groups are used)")
        self._spare_group = spare[0]
        self._cam_ids = {
            name: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
            for name in (world.camera_left, world.camera_right)
        }
        if min(self._cam_ids.values()) < 0:
            raise ValueError(f"world model lacks camera(s) {world.camera_left!r}/{world.camera_right!r}")
        self._gl = None
        self._ctx = None
        self._scene = None
        self._option = mujoco.MjvOption()
        self._amodal_option = mujoco.MjvOption()
        self._amodal_option.geomgroup[:] = 0
        self._amodal_option.geomgroup[self._spare_group] = 1
        self._amodal_option.sitegroup[:] = 0
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)

    # -- GL resources -------------------------------------------------------------------------
    def _ensure_context(self) -> None:
        if self._ctx is not None:
            return
        model = self.world.model
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), self.width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), self.height)
        model.vis.quality.offsamples = int(self.config.msaa_samples)
        self._gl = mujoco.GLContext(self.width, self.height)
        self._gl.make_current()
        self._ctx = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._ctx)
        self._ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom + 100))
        self._rgb_buf = np.empty((self.height, self.width, 3), np.uint8)
        self._depth_buf = np.empty((self.height, self.width), np.float32)

    def close(self) -> None:
        if self._ctx is not None:
            self._gl.make_current()
            self._ctx.free()
            self._gl.free()
        self._ctx = self._gl = self._scene = None

    def __enter__(self) -> "StereoRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- passes -----------------------------------------------------------------------------
    def _update(self, camera: str, option: mujoco.MjvOption) -> None:
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        cam.fixedcamid = self._cam_ids[camera]
        mujoco.mjv_updateScene(self.world.model, self.world.data, option, None, cam,
                               mujoco.mjtCatBit.mjCAT_ALL.value, self._scene)

    def _colour(self) -> np.ndarray:
        mujoco.mjr_render(self._rect, self._scene, self._ctx)
        mujoco.mjr_readPixels(self._rgb_buf, None, self._rect, self._ctx)
        return np.ascontiguousarray(self._rgb_buf[::-1])

    def _labels(self, with_depth: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Segmentation pass of the current scene.

        Returns bottom-up (GL row order) actor labels HxW uint16 (0 = no actor), a mask of pixels where
        any geom was drawn, and the raw depth buffer (or None).
        """
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        try:
            mujoco.mjr_render(self._rect, self._scene, self._ctx)
            mujoco.mjr_readPixels(self._rgb_buf, self._depth_buf if with_depth else None, self._rect, self._ctx)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
        ngeom = self._scene.ngeom
        lut = np.zeros(ngeom + 2, dtype=np.int64)  # colour code = segid + 1; 0 = nothing drawn
        geoms = self._scene.geoms[:ngeom]
        objtype = np.fromiter((g.objtype for g in geoms), np.int64, ngeom)
        objid = np.fromiter((g.objid for g in geoms), np.int64, ngeom)
        segid = np.fromiter((g.segid for g in geoms), np.int64, ngeom)
        is_geom = (objtype == _GEOM) & (segid >= 0)
        lut[segid[is_geom] + 1] = self._geom_label[objid[is_geom]]
        buf = self._rgb_buf
        code = buf[..., 0].astype(np.int32)
        code |= buf[..., 1].astype(np.int32) << 8
        code |= buf[..., 2].astype(np.int32) << 16
        np.minimum(code, ngeom + 1, out=code)
        drawn = code > 0
        return lut[code].astype(np.uint16), drawn, (self._depth_buf if with_depth else None)

    def _metric_depth(self, raw: np.ndarray, drawn: np.ndarray) -> np.ndarray:
        """Reverse-Z depth buffer -> metric z along the optical axis (as mujoco.Renderer), 0 where nothing was hit."""
        model = self.world.model
        near = np.float32(model.vis.map.znear * model.stat.extent)
        far = np.float32(model.vis.map.zfar * model.stat.extent)
        c_coef = np.float32(-0.5) * (-(far + near) / (far - near)) - np.float32(0.5)
        d_coef = np.float32(-0.5) * (-(np.float32(2) * far * near) / (far - near))
        z = d_coef / (raw.astype(np.float64) + c_coef)
        return np.where(drawn, z, 0.0).astype(np.float32)[::-1].copy()

    def _actor_rects(self, idx: np.ndarray, T_c_m: np.ndarray, intrinsics) -> np.ndarray:
        """Conservative image rects (u0, v0, u1, v1) of actors `idx` from their geoms' bounding boxes."""
        model, data = self.world.model, self.world.data
        geoms = np.concatenate([self._actor_geoms[k] for k in idx])
        owner = np.concatenate([np.full(len(self._actor_geoms[k]), j) for j, k in enumerate(idx)])
        corners_m = box_corners_from_aabb(model.geom_aabb[geoms], data.geom_xpos[geoms],
                                          data.geom_xmat[geoms].reshape(-1, 3, 3))
        corners_c = corners_m @ T_c_m[:3, :3].T + T_c_m[:3, 3]
        rects, _ = project_box_rects(corners_c, intrinsics, self.config.box_near_m)
        out = np.empty((len(idx), 4))
        for j in range(4):  # min/max over each actor's geoms
            reducer = np.minimum if j < 2 else np.maximum
            vals = np.full(len(idx), np.inf if j < 2 else -np.inf)
            reducer.at(vals, owner, rects[:, j])
            out[:, j] = vals
        return out

    def _amodal(self, visible: np.ndarray, T_c_m: np.ndarray, intrinsics) -> np.ndarray:
        """Pixel count of each visible actor rendered alone (amodal mask inside the image)."""
        n = len(self._actors)
        amodal = np.zeros(n, dtype=np.int64)
        if len(visible) == 0:
            return amodal
        model = self.world.model
        rects = self._actor_rects(visible, T_c_m, intrinsics)
        saved = model.geom_group.copy()
        try:
            for group in share_passes(rects):
                members = visible[group]
                model.geom_group[:] = saved
                model.geom_group[np.concatenate([self._actor_geoms[k] for k in members])] = self._spare_group
                self._update(self.world.camera_left, self._amodal_option)
                labels, _, _ = self._labels(with_depth=False)
                counts = np.bincount(labels.ravel(), minlength=n + 1)
                amodal[members] = counts[members + 1]
        finally:
            model.geom_group[:] = saved
        return amodal

    # -- public -----------------------------------------------------------------------------
    def render(self, T_m_c: np.ndarray, intrinsics: tuple[float, float, float, float],
               right: bool = True, depth: bool = True) -> RenderedFrame:
        """Render the world's current state (after `world.set_time`).

        T_m_c: left camera pose in the MuJoCo world (OpenCV axes), used to project actor boxes;
        intrinsics: (fx, fy, cx, cy) of the rendered images.
        """
        self._ensure_context()
        t0 = time.perf_counter()
        self._update(self.world.camera_left, self._option)
        left = self._colour()
        t1 = time.perf_counter()
        labels, drawn, raw_depth = self._labels(with_depth=depth)
        depth_m = self._metric_depth(raw_depth, drawn) if depth else None
        labels = labels[::-1]
        n = len(self._actors)
        visible_px, box2d = label_stats(labels, n)
        mots = np.concatenate([[0], self._mots]).astype(np.uint16)
        instances = mots[labels]
        t2 = time.perf_counter()
        amodal = self._amodal(np.flatnonzero(visible_px > 0), np.linalg.inv(T_m_c), intrinsics)
        t3 = time.perf_counter()
        right_img = None
        if right:
            self._update(self.world.camera_right, self._option)
            right_img = self._colour()
        t4 = time.perf_counter()
        t = {"left_rgb": (t1 - t0) * 1e3, "seg_depth": (t2 - t1) * 1e3, "amodal": (t3 - t2) * 1e3,
             "right_rgb": (t4 - t3) * 1e3}
        return RenderedFrame(left, right_img, depth_m, instances, visible_px, amodal, box2d, t)
