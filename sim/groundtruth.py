"""Per-frame ground truth in the sequence world (world = left camera at frame 0, OpenCV axes).

The MuJoCo world (x forward along the street, z up) is converted here and only here:
`T_w_m = inv(T_m_c(frame 0))`, so `T_w_c = T_w_m @ T_m_c`, `T_w_o = T_w_m @ T_m_o`, and velocities
rotate with `R_w_m`. Objects keep the GT box frame (box centre, x forward, y left, z up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dynaslam2.geometry.camera import StereoCamera
from dynaslam2.io.types import ObjectState

# Corner k of a box has sign bit 0 -> x, bit 1 -> y, bit 2 -> z (0: -half, 1: +half).
_CORNER_SIGNS = np.array([[(k >> b & 1) * 2 - 1 for b in range(3)] for k in range(8)], dtype=float)
# The 12 edges join corners that differ in exactly one sign bit.
BOX_EDGES = np.array([(k, k | 1 << b) for b in range(3) for k in range(8) if not k >> b & 1])


@dataclass(frozen=True)
class GroundTruthConfig:
    """Thresholds of the per-object ground truth.

    min_visible_px: an object is listed in a frame when at least this many of its pixels are visible.
    occlusion_full_visible: visible fraction at or above which KITTI occlusion level is 0 (fully visible).
    occlusion_largely: visible fraction below which the level is 2 (largely occluded); in between: 1.
      Level 3 (unknown) is given when no amodal pixel count is available.
    box_near_m: near plane (m) at which projected 3D box edges are clipped for the 2D extent.
    """

    min_visible_px: int = 1
    occlusion_full_visible: float = 0.95
    occlusion_largely: float = 0.5
    box_near_m: float = 0.05


def box_corners(dims: np.ndarray) -> np.ndarray:
    """(N, 3) box dims (l, w, h) -> (N, 8, 3) corners in the box frame (centred)."""
    return 0.5 * np.asarray(dims, dtype=float)[:, None, :] * _CORNER_SIGNS


def box_corners_from_aabb(aabb: np.ndarray, xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    """MuJoCo geom bounding boxes (G, 6: centre, half-size in the geom frame) at poses (xpos, xmat)
    -> (G, 8, 3) corners in the MuJoCo world."""
    local = aabb[:, None, :3] + aabb[:, None, 3:] * _CORNER_SIGNS
    return np.einsum("gij,gkj->gki", xmat, local) + xpos[:, None, :]


def project_box_rects(corners_c: np.ndarray, intrinsics, z_near: float) -> tuple[np.ndarray, np.ndarray]:
    """2D extent (u0, v0, u1, v1) of boxes given by (N, 8, 3) corners in a camera frame.

    The 12 edges are clipped at the plane z = z_near first, so boxes partly behind the camera get the
    extent of their visible part. Returns rects (N, 4) (NaN where the box lies wholly behind z_near)
    and in_front (N,) bool.
    """
    fx, fy, cx, cy = intrinsics
    a = corners_c[:, BOX_EDGES[:, 0]]
    b = corners_c[:, BOX_EDGES[:, 1]]
    za, zb = a[..., 2], b[..., 2]
    crosses = (za - z_near) * (zb - z_near) < 0
    s = np.where(crosses, (z_near - za) / np.where(crosses, zb - za, 1.0), 0.0)
    cut = a + s[..., None] * (b - a)
    pts = np.concatenate([corners_c, cut], axis=1)
    valid = np.concatenate([corners_c[..., 2] >= z_near, crosses], axis=1)
    z = np.where(valid, pts[..., 2], 1.0)
    u = np.where(valid, fx * pts[..., 0] / z + cx, np.nan)
    v = np.where(valid, fy * pts[..., 1] / z + cy, np.nan)
    in_front = valid.any(axis=1)
    rects = np.full((len(corners_c), 4), np.nan)
    if in_front.any():
        f = in_front
        rects[f] = np.stack([np.nanmin(u[f], 1), np.nanmin(v[f], 1), np.nanmax(u[f], 1), np.nanmax(v[f], 1)], 1)
    return rects, in_front


def truncation(rects: np.ndarray, width: int, height: int) -> np.ndarray:
    """Fraction of each 2D rect's area outside the image [-0.5, W-0.5] x [-0.5, H-0.5] (KITTI truncation)."""
    w = np.clip(rects[:, 2], -0.5, width - 0.5) - np.clip(rects[:, 0], -0.5, width - 0.5)
    h = np.clip(rects[:, 3], -0.5, height - 0.5) - np.clip(rects[:, 1], -0.5, height - 0.5)
    area = (rects[:, 2] - rects[:, 0]) * (rects[:, 3] - rects[:, 1])
    inside = np.where(area > 0, w * h / np.where(area > 0, area, 1.0), 0.0)
    return np.clip(1.0 - inside, 0.0, 1.0)


def occlusion_levels(visible_fraction: np.ndarray, amodal_px: np.ndarray, cfg: GroundTruthConfig) -> np.ndarray:
    """KITTI occlusion level per object: 0 fully visible, 1 partly, 2 largely occluded, 3 unknown."""
    level = np.where(visible_fraction >= cfg.occlusion_full_visible, 0,
                     np.where(visible_fraction >= cfg.occlusion_largely, 1, 2))
    return np.where(amodal_px > 0, level, 3)


class GroundTruth:
    """Converts world states into per-frame sequence ground truth; the sequence world is fixed at frame 0."""

    def __init__(self, world, camera: StereoCamera, cfg: GroundTruthConfig = GroundTruthConfig()):
        self.world = world
        self.camera = camera
        self.cfg = cfg
        self.T_w_m = np.linalg.inv(world.ego_T_m_c(0.0))
        self.dims = np.array([a.dims for a in world.actors], dtype=float).reshape(-1, 3)

    def camera_pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(T_w_c, T_m_c) of the left camera at time t."""
        T_m_c = self.world.ego_T_m_c(t)
        return self.T_w_m @ T_m_c, T_m_c

    def objects(self, t: float, T_w_c: np.ndarray, visible_px: np.ndarray, amodal_px: np.ndarray,
                box2d: np.ndarray) -> list[ObjectState]:
        """ObjectStates of the actors visible at time t (>= min_visible_px pixels, which lie in front of the
        camera by construction; an actor passing beside the camera is listed while any part of it shows,
        so every instance id in the image has its object)."""
        actors = self.world.actors
        if not actors:
            return []
        states = self.world.actor_states(t)
        T_m_o = np.stack([s[0] for s in states])
        v_m = np.stack([s[1] for s in states])
        w_m = np.stack([s[2] for s in states])
        T_w_o = self.T_w_m @ T_m_o
        R_w_m = self.T_w_m[:3, :3]
        v_w, w_w = v_m @ R_w_m.T, w_m @ R_w_m.T
        T_c_o = np.linalg.inv(T_w_c) @ T_w_o
        corners_c = box_corners(self.dims) @ np.swapaxes(T_c_o[:, :3, :3], 1, 2) + T_c_o[:, None, :3, 3]
        cam = self.camera
        rects, _ = project_box_rects(corners_c, (cam.fx, cam.fy, cam.cx, cam.cy), self.cfg.box_near_m)
        trunc = truncation(np.nan_to_num(rects), cam.width, cam.height)
        vis_frac = np.where(amodal_px > 0, np.minimum(visible_px / np.maximum(amodal_px, 1), 1.0), 0.0)
        level = occlusion_levels(vis_frac, amodal_px, self.cfg)
        listed = np.flatnonzero(visible_px >= max(self.cfg.min_visible_px, 1))
        return [
            ObjectState(
                track_id=int(actors[k].track_id), cls=actors[k].cls, T_w_o=T_w_o[k], v_w=v_w[k], w_w=w_w[k],
                dims=tuple(float(d) for d in self.dims[k]), visible_fraction=float(vis_frac[k]),
                truncation=float(trunc[k]), occlusion=int(level[k]),
                box2d=tuple(float(x) for x in box2d[k]),
            )
            for k in listed
        ]
