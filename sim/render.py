"""Stereo rendering of the street world: left/right RGB, left metric depth, instance ids, amodal pixel counts.

Passes per frame (each output renders only what it needs):
- left colour pass: RGB;
- left segmentation pass: geom ids AND the depth buffer, read from the same pass (metric z along the
  optical axis, 0 where no geom was hit);
- amodal passes, one per visible actor: its geoms are moved to a spare geom group and only that
  group is rendered, at full resolution but only inside the window of its conservatively projected
  bounding box (the camera frustum is narrowed to the window, which reproduces the full image's
  pixels exactly), so the count is its exact amodal mask inside the image at little cost;
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
from dynaslam2.config_tree import build, parse_overrides  # noqa: E402
from dynaslam2.errors import ConfigError  # noqa: E402
from sim.groundtruth import box_corners_from_aabb, project_box_rects  # noqa: E402

_GEOM = int(mujoco.mjtObj.mjOBJ_GEOM)
_NGROUP = 6  # mjNGROUP: geom groups 0..5


def _gl_context_class():
    """The GL context class for MUJOCO_GL (default egl), even when mujoco was imported before it was set."""
    backend = os.environ.get("MUJOCO_GL", "egl").lower()
    if backend == "egl":
        from mujoco.egl import GLContext
    elif backend == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        GLContext = mujoco.GLContext
    return GLContext


@dataclass(frozen=True)
class RenderConfig:
    """Rendering quality knobs.

    msaa_samples: multisample anti-aliasing of the colour passes (MuJoCo's `offsamples`; on Mesa's CPU rasterizer
      8 and 16 give the same images as 4). A camera integrates light over each pixel, so a silhouette falls
      between pixel values; drawn without it, a silhouette steps at whole pixels, placed in the left and right
      image independently, and stereo at object outlines measured that quantization: object keypoints whose SAD
      window holds another instance were 0.21 px off the rendered depth's disparity (median; 22 % over 0.5 px)
      against 0.06 px inside, with 4 samples 0.15 px (15 %) and 0.06 px (crossing s100, every 5th frame;
      benchmarks/bench_object_stereo.py). Instance ids and depth come out the same either way (tested). With 0
      the colour passes run 1.6-1.8x faster on the CPU (`dynaslam2 bench sim`).
    box_near_m: near plane (m) at which actor boxes are clipped when projected to find their image window.
    amodal_crop: render each actor's amodal pass only in the window of its projected box (pixel-exact
      with the full-image pass, which `False` selects; kept for verification).
    mesh_slices, mesh_stacks: tessellation of cylinders and ellipsoids (wheels, poles, trees; MuJoCo's
      `numslices`/`numstacks`, default 28/16): vertex work dominates the CPU rasterizer's cost.
    """

    msaa_samples: int = 4
    box_near_m: float = 0.05
    amodal_crop: bool = True
    mesh_slices: int = 12
    mesh_stacks: int = 8

    def validate(self) -> None:
        """ConfigError naming the first field out of range."""
        if self.msaa_samples < 0:
            raise ConfigError(f"msaa_samples: expected >= 0 (0 = no anti-aliasing), got {self.msaa_samples}")
        if not self.box_near_m > 0:
            raise ConfigError(f"box_near_m: expected a distance > 0 m, got {self.box_near_m}")
        if self.mesh_slices < 3 or self.mesh_stacks < 2:
            raise ConfigError(f"mesh_slices, mesh_stacks: expected >= 3 and >= 2, got {self.mesh_slices}, "
                              f"{self.mesh_stacks}")


def load_render_config(overrides: list[str] | tuple[str, ...] = ()) -> RenderConfig:
    """RenderConfig's defaults with `key=value` overrides (`dynaslam2 simulate --render-set`); bad keys or
    values raise ConfigError naming them."""
    return build(RenderConfig, parse_overrides(list(overrides), flag="--render-set"))


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

    Returns counts (n,) and boxes (n, 4) float (NaN where a label has no pixel). Vectorized over the
    labelled pixels only: bincounts of (label, row) and (label, column) give each label's rows/columns.
    """
    H, W = labels.shape
    flat = np.ascontiguousarray(labels).ravel()
    idx = np.flatnonzero(flat)
    lab = flat[idx].astype(np.intp)
    rows_of, cols_of = np.divmod(idx, W)
    rows = np.bincount(lab * H + rows_of, minlength=(n + 1) * H).reshape(n + 1, H)[1:] > 0
    cols = np.bincount(lab * W + cols_of, minlength=(n + 1) * W).reshape(n + 1, W)[1:] > 0
    counts = np.bincount(lab, minlength=n + 1)[1:]
    boxes = np.stack(
        [cols.argmax(1), rows.argmax(1), W - 1 - cols[:, ::-1].argmax(1), H - 1 - rows[:, ::-1].argmax(1)], 1
    ).astype(float)
    boxes[counts == 0] = np.nan
    return counts, boxes


def crop_window(rect: np.ndarray, width: int, height: int) -> tuple[int, int, int, int]:
    """Pixel window (col0, col1, row0, row1), half-open, holding every pixel centre inside a continuous
    rect (u0, v0, u1, v1) plus a one-pixel margin, clipped to the image; the whole image for a NaN rect."""
    if not np.all(np.isfinite(rect)):
        return 0, width, 0, height
    u0, v0, u1, v1 = rect
    c0 = int(np.clip(np.ceil(u0) - 1, 0, width))
    c1 = int(np.clip(np.floor(u1) + 2, 0, width))
    r0 = int(np.clip(np.ceil(v0) - 1, 0, height))
    r1 = int(np.clip(np.floor(v1) + 2, 0, height))
    return c0, c1, r0, r1


def crop_frustum(cam, window: tuple[int, int, int, int], width: int, height: int) -> None:
    """Narrow a scene camera's frustum (MjvGLCamera, set by mjv_updateScene for a full width x height
    image) to a pixel window, so that rendering into a window-sized viewport reproduces exactly those
    pixels of the full image (same sample positions)."""
    c0, c1, r0, r1 = window
    top, bottom = cam.frustum_top, cam.frustum_bottom
    half_w = cam.frustum_width if cam.frustum_width > 0 else 0.5 * width / height * (top - bottom)
    left = cam.frustum_center - half_w
    l_new = left + 2 * half_w * c0 / width
    r_new = left + 2 * half_w * c1 / width
    cam.frustum_center = 0.5 * (l_new + r_new)
    cam.frustum_width = 0.5 * (r_new - l_new)
    cam.frustum_top = top - (top - bottom) * r0 / height
    cam.frustum_bottom = top - (top - bottom) * r1 / height


def pack_windows(windows: list[tuple[int, int, int, int]], buf_w: int, buf_h: int) -> list[list[tuple[int, tuple[int, int]]]]:
    """Shelf-pack pixel windows (c0, c1, r0, r1) into pages of a buf_w x buf_h buffer.

    Returns pages, each a list of (window index, (x, y) offset in the buffer); tallest windows first.
    """
    order = sorted(range(len(windows)), key=lambda j: (-(windows[j][3] - windows[j][2]), j))
    pages, page = [], []
    x = y = shelf = 0
    for j in order:  # over actors, not pixels
        w, h = windows[j][1] - windows[j][0], windows[j][3] - windows[j][2]
        if x + w > buf_w:
            x, y, shelf = 0, y + shelf, 0
        if y + h > buf_h:
            pages.append(page)
            page, x, y, shelf = [], 0, 0, 0
        page.append((j, (x, y)))
        x += w
        shelf = max(shelf, h)
    if page:
        pages.append(page)
    return pages


class StereoRenderer:
    """Renders a `sim.world.World` from its left/right cameras. Use as a context manager or call close().

    The world's model gets `offwidth/offheight` raised to the image size and `offsamples`,
    `numslices`, `numstacks` set from the RenderConfig before the (lazy) GL context is made.
    """

    def __init__(self, world, width: int, height: int, config: RenderConfig = RenderConfig()):
        self.world = world
        self.width, self.height = int(width), int(height)
        self.config = config
        model = world.model
        self._actors = list(world.actors)
        n = len(self._actors)
        self._mots_lut = np.concatenate([[0], mots_ids(self._actors)]).astype(np.uint16)  # label -> MOTS id
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
    def ensure_context(self) -> None:
        """Create the GL context and upload the model (textures, meshes) now; render() calls this lazily."""
        if self._ctx is not None:
            return
        model = self.world.model
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), self.width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), self.height)
        model.vis.quality.offsamples = int(self.config.msaa_samples)
        model.vis.quality.numslices = int(self.config.mesh_slices)
        model.vis.quality.numstacks = int(self.config.mesh_stacks)
        self._gl = _gl_context_class()(self.width, self.height)
        self._gl.make_current()
        self._ctx = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._ctx)
        self._ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom + 100))
        self._rgb_buf = np.empty((self.height, self.width, 3), np.uint8)
        self._buf_w = int(self._ctx.offWidth)
        self._buf_h = int(self._ctx.offHeight)
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
        lut = np.zeros(ngeom + 2, dtype=np.uint16)  # colour code = segid + 1; 0 = nothing drawn
        geoms = self._scene.geoms[:ngeom]
        objtype = np.fromiter((g.objtype for g in geoms), np.int64, ngeom)
        objid = np.fromiter((g.objid for g in geoms), np.int64, ngeom)
        segid = np.fromiter((g.segid for g in geoms), np.int64, ngeom)
        is_geom = (objtype == _GEOM) & (segid >= 0)
        lut[segid[is_geom] + 1] = self._geom_label[objid[is_geom]]
        buf = self._rgb_buf
        if ngeom + 1 < 1 << 16:  # codes fit in the red and green bytes
            code = buf[..., 1].astype(np.uint16) << 8
            code |= buf[..., 0]
        else:
            code = buf[..., 0].astype(np.int32)
            code |= buf[..., 1].astype(np.int32) << 8
            code |= buf[..., 2].astype(np.int32) << 16
        np.minimum(code, ngeom + 1, out=code)
        return lut[code], code > 0, (self._depth_buf if with_depth else None)

    def _metric_depth(self, raw: np.ndarray, drawn: np.ndarray) -> np.ndarray:
        """Reverse-Z depth buffer -> metric z along the optical axis (as mujoco.Renderer), 0 where nothing was hit."""
        model = self.world.model
        near = np.float32(model.vis.map.znear * model.stat.extent)
        far = np.float32(model.vis.map.zfar * model.stat.extent)
        c_coef = np.float32(-0.5) * (-(far + near) / (far - near)) - np.float32(0.5)
        d_coef = np.float32(-0.5) * (-(np.float32(2) * far * near) / (far - near))
        z = raw + c_coef  # float32: relative error ~1e-7, i.e. 2 um at 20 m
        np.divide(d_coef, z, out=z)
        z[~drawn] = 0.0
        return z[::-1].copy()

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
            reducer = np.fmin if j < 2 else np.fmax  # NaN (geom behind the camera) ignored
            vals = np.full(len(idx), np.inf if j < 2 else -np.inf)
            reducer.at(vals, owner, rects[:, j])
            out[:, j] = vals
        return out

    def _amodal(self, visible: np.ndarray, T_c_m: np.ndarray, intrinsics) -> np.ndarray:
        """Pixel count of each visible actor rendered alone (its exact amodal mask inside the image).

        Per actor, only its geoms (moved to the spare group) are rendered, at full resolution but only
        in the window of its conservative projected box (`RenderConfig.amodal_crop`; else the whole
        image). The windows are packed side by side into the offscreen buffer and read back at once:
        one GPU sync per page instead of one per actor.
        """
        n = len(self._actors)
        amodal = np.zeros(n, dtype=np.int64)
        if len(visible) == 0:
            return amodal
        model = self.world.model
        if self.config.amodal_crop:
            rects = self._actor_rects(visible, T_c_m, intrinsics)
            windows = [crop_window(rect, self.width, self.height) for rect in rects]
        else:
            windows = [(0, self.width, 0, self.height)] * len(visible)
        saved = model.geom_group.copy()
        flags = self._scene.flags
        try:
            for page in pack_windows(windows, self._buf_w, self._buf_h):
                used_h = max(y + windows[j][3] - windows[j][2] for j, (_, y) in page)
                for j, (x, y) in page:
                    geoms = self._actor_geoms[visible[j]]
                    model.geom_group[geoms] = self._spare_group
                    self._update(self.world.camera_left, self._amodal_option)
                    model.geom_group[geoms] = saved[geoms]
                    c0, c1, r0, r1 = windows[j]
                    for cam in (self._scene.camera[0], self._scene.camera[1]):
                        crop_frustum(cam, windows[j], self.width, self.height)
                    flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
                    flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
                    try:
                        mujoco.mjr_render(mujoco.MjrRect(x, y, c1 - c0, r1 - r0), self._scene, self._ctx)
                    finally:
                        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 0
                        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 0
                atlas = np.empty((used_h, self._buf_w, 3), np.uint8)
                mujoco.mjr_readPixels(atlas, None, mujoco.MjrRect(0, 0, self._buf_w, used_h), self._ctx)
                drawn = atlas.max(axis=2) > 0  # only one actor's geoms are drawn in each window
                for j, (x, y) in page:
                    c0, c1, r0, r1 = windows[j]
                    amodal[visible[j]] = np.count_nonzero(drawn[y:y + r1 - r0, x:x + c1 - c0])
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
        self.ensure_context()
        self._gl.make_current()  # another renderer's context may be current
        t0 = time.perf_counter()
        self._update(self.world.camera_left, self._option)
        left = self._colour()
        t1 = time.perf_counter()
        labels, drawn, raw_depth = self._labels(with_depth=depth)
        depth_m = self._metric_depth(raw_depth, drawn) if depth else None
        labels = np.ascontiguousarray(labels[::-1])
        visible_px, box2d = label_stats(labels, len(self._actors))
        instances = self._mots_lut[labels]
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
