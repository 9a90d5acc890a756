"""The MuJoCo street world: scenery, textured vehicles and pedestrians on mocap bodies, stereo rig.

Frames: `m` is the MuJoCo world (z up, road surface at z = 0). The street starts along +x and then
bends by `curve_deg` (road and sidewalks are meshes that follow the bend exactly; everything is
planned in street coordinates and mapped by `StreetLayout.to_world`). Each actor
is one mocap root body whose origin is the centre of its 3D box (x forward, y left, z up) and whose
geoms fill that box exactly (dims = (length, width, height)). The ego is a mocap body carrying the
cameras `left` and `right` (right = left + baseline along the camera x axis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from sim import textures as tex
from sim.motion import CAMERA_FORWARD, MotionPlan, PlannedActor, StreetLayout, Trajectory, plan_scenario
from sim.scenarios import ScenarioConfig

# Bumped whenever the rendered world changes for the same scenario config and seed, so that cached sequences
# (benchmarks) are not silently stale. 2: vehicle paint and glass undistorted (were stretched per box face).
# 3: `crossing`'s turning vehicles slow for the turn (turned at up to 2.5 rad/s, 10-24 m/s^2 lateral).
# 4: colour passes anti-aliased (`sim.render.RenderConfig.msaa_samples` 0 -> 4; ids and depth unchanged).
WORLD_VERSION = 4

# OpenCV camera axes (x right, y down, z forward) expressed in the ego body frame (x fwd, y left, z up)
R_BODY_CV = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
_VISUAL = dict(contype=0, conaffinity=0)
_ROAD_SEGMENT = 20.0  # m of road per texture
_TEXTURE_POOL = 8  # distinct road / sidewalk textures per world
_RIBBON_STEP = 2.5  # m between cross-sections of road and sidewalk meshes


def camera_intrinsics(cfg: ScenarioConfig) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of both cameras: fx = fy = (H/2)/tan(fovy/2), principal point at the image centre."""
    w, h = cfg.image_size
    f = 0.5 * h / math.tan(math.radians(cfg.fovy_effective_deg) / 2.0)
    return f, f, (w - 1) / 2.0, (h - 1) / 2.0


@dataclass
class Actor:
    track_id: int  # 1..N, stable per actor
    cls: str  # "car" | "van" | "truck" | "pedestrian"
    dims: tuple[float, float, float]  # (length, width, height) m of its 3D box
    body_id: int  # mujoco body id (root, mocap)
    parked: bool


def _yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """(N, 4) MuJoCo quaternions (w, x, y, z) of rotations about +z."""
    yaw = np.asarray(yaw, float)
    return np.stack([np.cos(yaw / 2), np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2)], axis=-1)


def _yaw_rot(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class World:
    """A compiled street scene and its motion; `set_time(t)` poses everything for time t."""

    camera_left: str = "left"
    camera_right: str = "right"

    def __init__(self, model: mujoco.MjModel, cfg: ScenarioConfig, plan: MotionPlan, actors: list[Actor],
                 ego_body: int, trajectories: list[Trajectory]):
        self.model = model
        self.data = mujoco.MjData(model)
        self.cfg = cfg
        self.plan = plan
        self.actors = actors
        self._trajectories = trajectories
        self._heights = np.array([a.dims[2] for a in actors], float)
        self._mocap_ids = np.array([model.body_mocapid[a.body_id] for a in actors], int)
        self._ego_mocap = int(model.body_mocapid[ego_body])
        self._frame_xyq, self._frame_vel, self._frame_ego = self._evaluate(np.arange(cfg.frames) / cfg.fps)
        self.set_time(0.0)

    def _evaluate(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Actor poses (T, N, 3) as (x, y, yaw), velocities (T, N, 3) as (vx, vy, yaw rate), ego (T, 3)."""
        n = len(self._trajectories)
        xyq = np.empty((len(times), n, 3))
        vel = np.empty((len(times), n, 3))
        lay = self.plan.layout
        for i, traj in enumerate(self._trajectories):
            xyq[:, i] = np.column_stack(lay.world_pose(traj, times))
            vel[:, i] = np.column_stack(lay.world_velocity(traj, times))
        return xyq, vel, np.column_stack(lay.world_pose(self.plan.ego, times))

    def _state(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(xyq (N, 3), vel (N, 3), ego (3,)) at t; frame times come from a table made once."""
        k = t * self.cfg.fps
        ki = int(round(k))
        if abs(k - ki) < 1e-9 and 0 <= ki < self._frame_xyq.shape[0]:
            return self._frame_xyq[ki], self._frame_vel[ki], self._frame_ego[ki]
        xyq, vel, ego = self._evaluate(np.array([float(t)]))
        return xyq[0], vel[0], ego[0]

    def set_time(self, t: float) -> None:
        """Write ego and actor mocap poses for time t, then mj_forward (cameras and geoms up to date)."""
        xyq, _, ego = self._state(t)
        if self.actors:
            self.data.mocap_pos[self._mocap_ids] = np.column_stack([xyq[:, :2], 0.5 * self._heights])
            self.data.mocap_quat[self._mocap_ids] = _yaw_quat(xyq[:, 2])
        self.data.mocap_pos[self._ego_mocap] = (ego[0], ego[1], 0.0)
        self.data.mocap_quat[self._ego_mocap] = _yaw_quat(ego[2])
        mujoco.mj_forward(self.model, self.data)

    def ego_T_m_c(self, t: float) -> np.ndarray:
        """4x4 pose of the left camera in the MuJoCo world, OpenCV axes (x right, y down, z forward)."""
        x, y, q = self._state(t)[2]
        R_m_b = _yaw_rot(q)
        T_m_c = np.eye(4)
        T_m_c[:3, :3] = R_m_b @ R_BODY_CV
        T_m_c[:3, 3] = np.array([x, y, 0.0]) + R_m_b @ np.array([CAMERA_FORWARD, 0.0, self.cfg.cam_height])
        return T_m_c

    def actor_states(self, t: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per actor: T_m_o (4x4, box centre, x fwd, y left, z up), v_m (3,), w_m (3,) in the MuJoCo world."""
        xyq, vel, _ = self._state(t)
        c, sn = np.cos(xyq[:, 2]), np.sin(xyq[:, 2])
        T = np.zeros((len(xyq), 4, 4))
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -sn, sn, c
        T[:, 2, 2] = T[:, 3, 3] = 1.0
        T[:, 0, 3], T[:, 1, 3], T[:, 2, 3] = xyq[:, 0], xyq[:, 1], 0.5 * self._heights
        zeros = np.zeros(len(xyq))
        v = np.column_stack([vel[:, 0], vel[:, 1], zeros])
        w = np.column_stack([zeros, zeros, vel[:, 2]])
        return [(T[i], v[i], w[i]) for i in range(len(xyq))]


class _Builder:
    """Adds textures, materials and geoms to an MjSpec with unique names."""

    def __init__(self, spec: mujoco.MjSpec, layout: StreetLayout, rich: bool, px: int):
        self.spec = spec
        self.layout = layout
        self.rich = rich
        self.px = px  # vehicle texture pixels per 4 m; facades up to twice that
        self.n = 0
        self.tile_m: dict[str, float] = {}  # materials mapped in metres (see `material`)

    def material(self, img: np.ndarray | None, rgba=(1, 1, 1, 1), specular: float = 0.1,
                 shininess: float = 0.2, tile_m: float | None = None) -> str:
        """A material, textured with img if given. MuJoCo stretches a 2D texture over each face of a box
        primitive (a car's 4 x 0.6 m side shows it squeezed 7:1, and `texuniform` does not undo that for
        boxes); with tile_m, `box` builds its boxes as meshes that show one undistorted copy of img per
        tile_m x tile_m metres of the body, continuous across the body's boxes."""
        self.n += 1
        name = f"mat{self.n}"
        mat = self.spec.add_material(name=name, rgba=list(rgba), specular=specular, shininess=shininess)
        if tile_m is not None:
            self.tile_m[name] = tile_m
        if img is not None:
            tname = f"tex{self.n}"
            t = self.spec.add_texture(name=tname, type=mujoco.mjtTexture.mjTEXTURE_2D, width=img.shape[1],
                                      height=img.shape[0], nchannel=3)
            t.data = np.ascontiguousarray(img, np.uint8).tobytes()
            mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tname
        return name

    def street_box(self, center, half, material: str, yaw: float = 0.0, name: str | None = None):
        """World box whose centre (x, y, z) and yaw are in street coordinates (follows the bend)."""
        X, Y, Q = self.layout.to_world(center[0], center[1], yaw)
        return self.box(self.spec.worldbody, (float(X), float(Y), center[2]), half, material,
                        quat=_yaw_quat(float(Q)).tolist(), name=name)

    def street_geom(self, gtype, size, center, material: str):
        """World cylinder/ellipsoid (vertical axis) at a street-coordinate centre."""
        X, Y, _ = self.layout.to_world(center[0], center[1])
        return self.spec.worldbody.add_geom(type=gtype, size=list(size), pos=[float(X), float(Y), center[2]],
                                            material=material, **_VISUAL)

    def ribbon(self, name: str, x_a: float, x_b: float, y_lo: float, y_hi: float, z_top: float, z_bot: float,
               material: str):
        """A slab mesh over street coordinates [x_a, x_b] x [y_lo, y_hi] that follows the bend exactly
        (neighbouring ribbons share their edges). Texture u runs along x, v from y_hi (row 0) to y_lo."""
        n = max(1, int(math.ceil((x_b - x_a) / _RIBBON_STEP)))
        xs = np.linspace(x_a, x_b, n + 1)
        u = (xs - x_a) / (x_b - x_a)
        X_lo, Y_lo, _ = self.layout.to_world(xs, np.full_like(xs, y_lo))
        X_hi, Y_hi, _ = self.layout.to_world(xs, np.full_like(xs, y_hi))
        verts, tcs, faces = [], [], []

        def strip(p0, p1, t0, t1, flip):
            """Quads between two polylines (n+1 points each), own vertices (sharp normals)."""
            base = sum(len(v) for v in verts)
            verts.append(np.concatenate([p0, p1]))
            tcs.append(np.concatenate([t0, t1]))
            i = np.arange(n)
            a, b, c, d = base + i, base + i + 1, base + n + 1 + i, base + n + 2 + i
            tri = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
            faces.append(tri[:, ::-1] if flip else tri)

        def pts(X, Y, z):
            return np.column_stack([X, Y, np.full_like(X, z)])

        t_lo, t_hi = np.column_stack([u, np.ones_like(u)]), np.column_stack([u, np.zeros_like(u)])
        strip(pts(X_lo, Y_lo, z_top), pts(X_hi, Y_hi, z_top), t_lo, t_hi, False)  # top, facing up
        strip(pts(X_lo, Y_lo, z_bot), pts(X_hi, Y_hi, z_bot), t_lo, t_hi, True)  # bottom
        strip(pts(X_lo, Y_lo, z_bot), pts(X_lo, Y_lo, z_top), t_lo, t_lo, False)  # side at y_lo
        strip(pts(X_hi, Y_hi, z_bot), pts(X_hi, Y_hi, z_top), t_hi, t_hi, True)  # side at y_hi
        self.spec.add_mesh(name=f"{name}_mesh", uservert=np.concatenate(verts).ravel().tolist(),
                           userface=np.concatenate(faces).ravel().tolist(),
                           usertexcoord=np.concatenate(tcs).ravel().tolist())
        return self.spec.worldbody.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"{name}_mesh",
                                            material=material, **_VISUAL)

    def box(self, body, center, half, material: str, quat=None, group: int = 0, name: str | None = None):
        """A box geom on body (centre and half sizes in the body frame); a mesh with metric texture
        coordinates if the material has a tile (see `material`)."""
        kw = dict(pos=list(center), material=material, group=group, **_VISUAL)
        if quat is not None:
            kw["quat"] = list(quat)
        if name is not None:
            kw["name"] = name
        if material not in self.tile_m:
            return body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half), **kw)
        self.n += 1
        mesh = f"uvbox{self.n}"
        vert, uv, face = _uv_box(np.asarray(center, float), np.asarray(half, float), self.tile_m[material])
        self.spec.add_mesh(name=mesh, uservert=vert.ravel().tolist(), userface=face.ravel().tolist(),
                           usertexcoord=uv.ravel().tolist())
        return body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh, **kw)


# Per box face: outward normal axis and sign, the face's (u, v) axes as (body axis, sign), and a (u, v)
# offset in tiles, so that opposite faces do not show the same patch.
_UV_FACES = (
    (1, 1.0, (0, 1.0), (2, -1.0), (0.0, 0.0)),  # left side (+y): u along x, v down
    (1, -1.0, (0, -1.0), (2, -1.0), (0.0, 0.5)),  # right side
    (0, 1.0, (1, -1.0), (2, -1.0), (0.25, 0.0)),  # front (+x)
    (0, -1.0, (1, 1.0), (2, -1.0), (0.75, 0.5)),  # rear
    (2, 1.0, (0, 1.0), (1, -1.0), (0.5, 0.25)),  # top
    (2, -1.0, (0, 1.0), (1, 1.0), (0.5, 0.75)),  # bottom
)


def _uv_box(center: np.ndarray, half: np.ndarray, tile_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(24x3 vertices relative to center, 24x2 texture coordinates, 12x3 triangles) of a box mesh whose faces
    take their texture coordinates from the body coordinates in tiles of tile_m metres (no stretch)."""
    verts, uvs, faces = [], [], []
    for k, (axis, sign, (ua, us), (va, vs), (u0, v0)) in enumerate(_UV_FACES):
        quad = np.empty((4, 3))
        quad[:, axis] = center[axis] + sign * half[axis]
        for i, (a, b) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
            quad[i, ua] = center[ua] + us * a * half[ua]
            quad[i, va] = center[va] + vs * b * half[va]
        verts.append(quad - center)
        uvs.append(np.column_stack([us * quad[:, ua] / tile_m + u0, vs * quad[:, va] / tile_m + v0]))
        tri = 4 * k + np.array([[0, 1, 2], [0, 2, 3]])
        normal = np.cross(quad[1] - quad[0], quad[2] - quad[0])
        faces.append(tri if normal[axis] * sign > 0 else tri[:, ::-1])  # counter-clockwise seen from outside
    return np.concatenate(verts), np.concatenate(uvs), np.concatenate(faces)


def build_world(cfg: ScenarioConfig) -> World:
    """Plan the motion for cfg.seed, build the scene with MjSpec, compile it and wrap it in a World."""
    seeds = np.random.SeedSequence(cfg.seed).spawn(3)
    plan = plan_scenario(cfg, seeds[0])
    rng_scene = np.random.default_rng(seeds[1])
    rng_actor = np.random.default_rng(seeds[2])
    spec = mujoco.MjSpec()
    spec.modelname = f"street_{cfg.name}_{cfg.seed}"
    b = _Builder(spec, plan.layout, cfg.texture == "rich", cfg.texture_px)
    _setup_visual(spec, cfg)
    _add_scenery(b, plan, cfg, rng_scene)
    bodies = []
    for i, pa in enumerate(plan.actors):
        body = spec.worldbody.add_body(name=f"actor{i + 1}", mocap=True, pos=[0, 0, pa.dims[2] / 2])
        if pa.cls == "pedestrian":
            _add_pedestrian(b, body, pa, rng_actor)
        else:
            _add_vehicle(b, body, pa, rng_actor)
        bodies.append(body.name)
    ego = spec.worldbody.add_body(name="ego", mocap=True)
    fovy = cfg.fovy_effective_deg
    ego.add_camera(name="left", pos=[CAMERA_FORWARD, 0.0, cfg.cam_height], xyaxes=[0, -1, 0, 0, 0, 1], fovy=fovy)
    ego.add_camera(name="right", pos=[CAMERA_FORWARD, -cfg.baseline, cfg.cam_height], xyaxes=[0, -1, 0, 0, 0, 1],
                   fovy=fovy)
    model = spec.compile()
    model.vis.map.znear = cfg.znear / model.stat.extent
    model.vis.map.zfar = cfg.zfar / model.stat.extent
    actors = [Actor(i + 1, pa.cls, pa.dims, model.body(name).id, pa.trajectory.is_static())
              for i, (pa, name) in enumerate(zip(plan.actors, bodies))]
    return World(model, cfg, plan, actors, model.body("ego").id, [pa.trajectory for pa in plan.actors])


def _setup_visual(spec: mujoco.MjSpec, cfg: ScenarioConfig) -> None:
    w, h = cfg.image_size
    spec.visual.global_.offwidth = max(w, 640)
    spec.visual.global_.offheight = max(h, 480)
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.35, 0.35, 0.35]
    spec.visual.headlight.specular = [0.05, 0.05, 0.05]
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0  # the renderer sets it from its RenderConfig
    spec.add_texture(name="sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX, builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                     rgb1=[0.55, 0.68, 0.88], rgb2=[0.92, 0.94, 0.98], width=256, height=256)
    spec.worldbody.add_light(name="sun", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, dir=[0.3, 0.5, -0.8],
                             diffuse=[0.55, 0.55, 0.52], specular=[0.1, 0.1, 0.1], castshadow=False)


def _add_scenery(b: _Builder, plan: MotionPlan, cfg: ScenarioConfig, rng: np.random.Generator) -> None:
    lay = plan.layout
    rich = b.rich
    x0, x1 = lay.x_lo - 30.0, lay.x_hi + 30.0
    lines = [0.0, lay.half_road, -lay.half_road]
    dashes = [s * i * lay.lane_width for i in range(1, lay.lanes_per_direction) for s in (-1, 1)]
    road_w = 2 * lay.kerb
    road_mats = [b.material(tex.asphalt(rng, road_w, _ROAD_SEGMENT, lines, dashes, rich=rich), specular=0.05)
                 for _ in range(_TEXTURE_POOL)]
    walk_mats = [b.material(tex.sidewalk(rng, cfg.sidewalk_width, _ROAD_SEGMENT, rich=rich), specular=0.05)
                 for _ in range(_TEXTURE_POOL)]
    n_seg = int(math.ceil((x1 - x0) / _ROAD_SEGMENT))
    order = rng.permutation(n_seg) % _TEXTURE_POOL
    sw_in, sw_out = lay.kerb, lay.kerb + cfg.sidewalk_width
    for i in range(n_seg):
        a, c = x0 + i * _ROAD_SEGMENT, x0 + (i + 1) * _ROAD_SEGMENT
        b.ribbon(f"road{i}", a, c, -lay.kerb, lay.kerb, 0.0, -0.1, road_mats[order[i]])
        for side in (-1, 1):
            mat = walk_mats[(order[i] + (3 if side > 0 else 0)) % _TEXTURE_POOL]
            y_lo, y_hi = (sw_in, sw_out) if side > 0 else (-sw_out, -sw_in)
            pieces = [(a, c)]
            if lay.x_int is not None:  # the crossing street cuts the sidewalks
                pieces = [(a, min(c, lay.x_int - lay.cross_half)), (max(a, lay.x_int + lay.cross_half), c)]
            for k, (pa, pc) in enumerate(pieces):
                if pc - pa > 0.05:
                    b.ribbon(f"sidewalk{i}_{side}_{k}", pa, pc, y_lo, y_hi, 0.15, 0.0, mat)
    if lay.x_int is not None:
        _add_intersection(b, lay, cfg, rng)
    _add_buildings(b, lay, cfg, rng, x0, x1)
    _add_props(b, plan, rng)


def _add_intersection(b: _Builder, lay, cfg: ScenarioConfig, rng: np.random.Generator) -> None:
    """Crossing street roads, crosswalk stripes, buildings along the crossing street."""
    length = 90.0
    mat = b.material(tex.asphalt(rng, 2 * lay.cross_half, length, [0.0], [], rich=b.rich), specular=0.05)
    for side in (-1, 1):
        yc = side * (lay.kerb + length / 2)
        b.street_box((lay.x_int, yc, -0.05), (length / 2, lay.cross_half, 0.05), mat, yaw=np.pi / 2)
        for xs in (-1, 1):  # sidewalks along the crossing street
            xc = lay.x_int + xs * (lay.cross_half + cfg.sidewalk_width / 2)
            smat = b.material(tex.sidewalk(rng, cfg.sidewalk_width, length, rich=b.rich), specular=0.05)
            b.street_box((xc, yc + side * cfg.sidewalk_width / 2, 0.075),
                         (length / 2, cfg.sidewalk_width / 2, 0.075), smat, yaw=np.pi / 2)
    paint = b.material(None, rgba=(0.88, 0.88, 0.85, 1), specular=0.05)
    for xs in (-1, 1):  # zebra stripes across the main street
        xc = lay.x_int + xs * (lay.cross_half + 2.0)
        y = -lay.kerb + 0.5
        while y < lay.kerb - 0.5:
            b.street_box((xc, y + 0.25, 0.002), (1.5, 0.25, 0.002), paint)
            y += 1.0
    for xs in (-1, 1):  # facades lining the crossing street
        for side in (-1, 1):
            y = lay.sidewalk_outer
            while y < lay.sidewalk_outer + 70.0:
                width = rng.uniform(8.0, 20.0)
                height = rng.uniform(6.0, 25.0)
                depth = rng.uniform(10.0, 14.0)
                xc = lay.x_int + xs * (lay.cross_half + cfg.sidewalk_width + depth / 2)
                fmat = b.material(tex.facade(rng, width, height, max_px=2 * b.px, rich=b.rich))
                b.street_box((xc, side * (y + width / 2), height / 2), (width / 2, depth / 2, height / 2), fmat,
                             yaw=np.pi / 2)
                y += width


def _add_buildings(b: _Builder, lay, cfg: ScenarioConfig, rng: np.random.Generator, x0: float, x1: float) -> None:
    forecourt = b.material(None, rgba=(0.55, 0.53, 0.5, 1))
    for side in (-1, 1):
        x = x0
        while x < x1:
            width = rng.uniform(8.0, 22.0)
            if rng.random() < 0.15:  # alley
                x += rng.uniform(2.0, 4.0)
            a, c = x, x + width
            x = c
            if lay.x_int is not None:
                cut = lay.cross_half + cfg.sidewalk_width
                if c > lay.x_int - cut and a < lay.x_int + cut:
                    continue
            height = rng.uniform(6.0, 28.0)
            depth = rng.uniform(10.0, 15.0)
            setback = rng.uniform(0.0, 1.5)
            yc = side * (lay.sidewalk_outer + setback + depth / 2)
            mat = b.material(tex.facade(rng, width, height, max_px=2 * b.px, rich=b.rich))
            b.street_box(((a + c) / 2, yc, height / 2), (width / 2, depth / 2, height / 2), mat,
                         name=f"building{side}_{int(round(a * 100))}")
            if setback > 0.05:  # forecourt pavement up to the facade
                b.street_box(((a + c) / 2, side * (lay.sidewalk_outer + setback / 2), 0.07),
                             (width / 2, setback / 2, 0.07), forecourt)
    span = lay.sidewalk_outer + 15.0
    for xe in (x0 - 8.0, x1 + 8.0):  # end walls closing the street
        height = rng.uniform(12.0, 25.0)
        mat = b.material(tex.facade(rng, 2 * span, height, max_px=2 * b.px, rich=b.rich))
        b.street_box((xe, 0.0, height / 2), (8.0, span, height / 2), mat)


def _add_props(b: _Builder, plan: MotionPlan, rng: np.random.Generator) -> None:
    barks = [b.material(tex.bark(rng, 128, rich=b.rich)) for _ in range(4)]
    leaves = [b.material(tex.foliage(rng, 128, rich=b.rich)) for _ in range(4)]
    metals = [b.material(tex.metal(rng, 64, rich=b.rich), specular=0.3) for _ in range(4)]
    lamp = b.material(None, rgba=(0.9, 0.9, 0.8, 1))
    for p in plan.props:
        k = int(rng.integers(4))
        if p.kind == "tree":
            trunk_h = rng.uniform(3.6, 4.5)
            b.street_geom(mujoco.mjtGeom.mjGEOM_CYLINDER, (rng.uniform(0.12, 0.2), trunk_h / 2),
                          (p.x, p.y, trunk_h / 2), barks[k])
            r = rng.uniform(1.3, 2.0)
            b.street_geom(mujoco.mjtGeom.mjGEOM_ELLIPSOID, (r, r, r * rng.uniform(0.9, 1.4)),
                          (p.x, p.y, trunk_h + r * 0.8), leaves[k])
        elif p.kind == "pole":
            h = rng.uniform(5.0, 7.0)
            b.street_geom(mujoco.mjtGeom.mjGEOM_CYLINDER, (0.09, h / 2), (p.x, p.y, h / 2), metals[k])
            inward = -np.sign(p.y)
            b.street_box((p.x, p.y + inward * 0.8, h), (0.25, 0.8, 0.06), metals[k])
            b.street_box((p.x, p.y + inward * 1.5, h - 0.1), (0.2, 0.15, 0.06), lamp)
            if rng.random() < 0.5:  # a sign board
                b.street_box((p.x, p.y, rng.uniform(2.2, 3.0)), (0.04, 0.35, 0.3),
                             b.material(tex.vehicle_paint(rng, 64, rich=b.rich)))
        elif p.kind == "hedge":
            h = rng.uniform(0.9, 1.4)
            b.street_box((p.x, p.y, 0.15 + h / 2), (p.length / 2, p.width / 2, h / 2), leaves[k])
        else:  # kiosk / advertising box
            h = rng.uniform(2.3, 2.9)
            b.street_box((p.x, p.y, 0.15 + h / 2), (p.length / 2, p.width / 2, h / 2),
                         b.material(tex.vehicle_paint(rng, 128, rich=b.rich)))


# Bottom of the bumpers/aprons at both ends of each vehicle class (m above the road): the box's bottom
# corners at the ends then carry geometry, so the projected 3D box is tight on the mask in the image.
_APRON_Z = {"car": 0.04, "van": 0.05, "truck": 0.08}
_APRON_LEN = {"car": 0.22, "van": 0.25, "truck": 0.3}  # m, shorter than the overhang ahead of the wheels


def _add_vehicle(b: _Builder, body, pa: PlannedActor, rng: np.random.Generator) -> None:
    """Boxes and wheels that fill the (L, W, H) box centred on the body origin exactly.

    Full-width aprons (bumpers, a truck's underrun guard) reach down to `_APRON_Z` at both ends and the
    highest part spans the full length/width where it meets the box's top corners seen by the camera,
    so that the 3D box is tight in the image, not only in 3D.
    """
    L, W, H = pa.dims
    size = int(np.clip(b.px * L / 4.0, 64, 1024))  # texture_px per 4 m
    paint = b.material(tex.vehicle_paint(rng, size, rich=b.rich, side_m=L), specular=0.4, shininess=0.6, tile_m=L)
    glass = b.material(tex.glass(rng, 128, rich=b.rich), specular=0.6, shininess=0.8, tile_m=W)
    tyre = b.material(None, rgba=(0.08, 0.08, 0.08, 1), specular=0.05)
    z0 = -H / 2  # ground in body coordinates
    r = {"car": 0.32, "van": 0.36, "truck": 0.5}[pa.cls]
    if pa.cls == "car":
        sill, belt = 0.25, 0.55 * H
        b.box(body, (0, 0, z0 + (sill + belt) / 2), (L / 2, W / 2, (belt - sill) / 2), paint)
        cab_l = 0.5 * L
        b.box(body, (-0.05 * L, 0, z0 + (belt + H) / 2), (cab_l / 2, 0.45 * W, (H - belt) / 2), glass)
        front_top = rear_top = sill
    elif pa.cls == "van":
        sill = 0.3
        hood_l = 0.18 * L
        b.box(body, (-hood_l / 2, 0, z0 + (sill + H) / 2), ((L - hood_l) / 2, W / 2, (H - sill) / 2), paint)
        b.box(body, (L / 2 - hood_l / 2, 0, z0 + (sill + 0.5 * H) / 2), (hood_l / 2, W / 2, (0.5 * H - sill) / 2),
              paint)
        b.box(body, (L / 2 - hood_l - 0.02, 0, z0 + 0.72 * H), (0.03, 0.42 * W, 0.14 * H), glass)
        front_top = rear_top = sill
    else:  # truck: chassis, full-height cab (roof fairing up to the cargo box), cargo box
        cab_l = 0.24 * L
        b.box(body, (0, 0, z0 + 0.75), (L / 2 - _APRON_LEN["truck"], 0.45 * W, 0.25), tyre)  # between the aprons
        b.box(body, (L / 2 - cab_l / 2, 0, z0 + (0.6 + 0.8 * H) / 2), (cab_l / 2, W / 2, (0.8 * H - 0.6) / 2),
              paint)
        b.box(body, (L / 2 - cab_l / 2 - 0.05, 0, z0 + 0.9 * H), (cab_l / 2 - 0.05, 0.47 * W, 0.1 * H), paint)  # fairing
        b.box(body, (L / 2 - 0.02, 0, z0 + 0.65 * H), (0.02, 0.4 * W, 0.1 * H), glass)
        cargo = b.material(tex.vehicle_paint(rng, size, rich=b.rich, side_m=L), specular=0.2, tile_m=L)
        b.box(body, (-(cab_l + 0.1) / 2, 0, z0 + (1.0 + H) / 2), ((L - cab_l - 0.1) / 2, W / 2, (H - 1.0) / 2), cargo)
        front_top, rear_top = 0.6, 1.0
    za, la = _APRON_Z[pa.cls], _APRON_LEN[pa.cls]
    for xs, top in ((1.0, front_top), (-1.0, rear_top)):  # bumpers / aprons below the body at both ends
        b.box(body, (xs * (L - la) / 2, 0, z0 + (za + top) / 2), (la / 2, W / 2, (top - za) / 2), paint)
    axle_x = L / 2 - r - 0.35 * (L / 4.5)
    quat = [math.cos(math.pi / 4), math.sin(math.pi / 4), 0, 0]  # cylinder axis along y
    for xs in (axle_x, -axle_x):  # one cylinder per axle: both wheels, half the geometry of four
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[r, W / 2 - 0.02], pos=[xs, 0.0, z0 + r],
                      quat=quat, material=tyre, **_VISUAL)


def _add_pedestrian(b: _Builder, body, pa: PlannedActor, rng: np.random.Generator) -> None:
    """Legs (one forward, one back), torso, arms, neck and head filling the (L, W, H) box exactly."""
    L, W, H = pa.dims
    z0 = -H / 2
    cloth = b.material(tex.clothing(rng, 64, rich=b.rich))
    skin = b.material(tex.skin(rng, 32, rich=b.rich))
    hip, shoulder, neck = 0.48 * H, 0.82 * H, 0.86 * H
    leg = 0.07
    for xs, ys in ((L / 2 - leg, 0.09), (-(L / 2 - leg), -0.09)):
        b.box(body, (xs, ys, z0 + hip / 2), (leg, 0.075, hip / 2), cloth)
    arm = 0.05
    b.box(body, (0, 0, z0 + (hip + shoulder) / 2), (0.13, W / 2 - 2 * arm, (shoulder - hip) / 2), cloth)
    for ys in (1, -1):
        b.box(body, (rng.uniform(-0.08, 0.08), ys * (W / 2 - arm), z0 + (hip - 0.05 + shoulder) / 2),
              (arm, arm, (shoulder - hip + 0.05) / 2), cloth)
    b.box(body, (0, 0, z0 + (shoulder + neck) / 2), (0.05, 0.05, (neck - shoulder) / 2), skin)
    b.box(body, (0.01, 0, z0 + (neck + H) / 2), (0.1, 0.085, (H - neck) / 2), skin)
