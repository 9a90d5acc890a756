"""The simulated street world: scenario loading, building, motion, determinism, camera model."""

import os

import cv2
import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
mujoco = pytest.importorskip("mujoco")

from dynaslam2.errors import ConfigError, InputError  # noqa: E402
from sim.scenarios import SCENARIOS, load_scenario  # noqa: E402
from sim.world import build_world, camera_intrinsics  # noqa: E402

SMALL = ["frames=12", "image_size=96x64", "texture_px=64", "view_ahead=60"]


@pytest.fixture(scope="module")
def traffic():
    return build_world(load_scenario("traffic", SMALL))


def test_load_builtins_overrides_and_yaml(tmp_path):
    cfg = load_scenario("traffic", ["seed=3", "frames=20", "image_size=640x480", "object_speed=1.5"])
    assert (cfg.name, cfg.seed, cfg.frames, cfg.image_size, cfg.object_speed) == ("traffic", 3, 20, (640, 480), 1.5)
    assert load_scenario("static", []).parked_fraction == 1.0
    assert SCENARIOS == ("static", "traffic", "crossing", "following")
    path = tmp_path / "mine.yaml"
    path.write_text("base: crossing\nseed: 7\nocclusion: 0.9\n")
    cfg = load_scenario(str(path), ["frames=5"])
    assert (cfg.name, cfg.layout, cfg.seed, cfg.occlusion, cfg.frames) == ("mine", "intersection", 7, 0.9, 5)


def test_bad_scenario_input():
    with pytest.raises(InputError, match="static, traffic, crossing, following"):
        load_scenario("motorway", [])
    with pytest.raises(ConfigError, match="warp_speed"):
        load_scenario("traffic", ["warp_speed=3"])
    with pytest.raises(ConfigError, match="occlusion"):
        load_scenario("traffic", ["occlusion=1.5"])
    with pytest.raises(ConfigError, match="texture"):
        load_scenario("traffic", ["texture=shiny"])
    with pytest.raises(ConfigError, match="image_size"):
        load_scenario("traffic", ["image_size=640"])
    with pytest.raises(ConfigError, match="frames"):
        load_scenario("traffic", ["frames=0"])


def _geom_extent_in_body(model, body_id):
    """(lo, hi) corners of the union of the geoms' boxes of one body, in the body frame."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for g in np.flatnonzero(model.geom_bodyid == body_id):
        c, h = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, model.geom_quat[g])
        corners = (np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T * h + c) @ R.reshape(3, 3).T
        corners += model.geom_pos[g]
        lo, hi = np.minimum(lo, corners.min(0)), np.maximum(hi, corners.max(0))
    return lo, hi


@pytest.mark.parametrize("name", SCENARIOS)
def test_every_builtin_builds_with_tight_boxes(name):
    world = build_world(load_scenario(name, SMALL))
    m = world.model
    assert len(world.actors) > 0
    assert [a.track_id for a in world.actors] == list(range(1, len(world.actors) + 1))
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    assert not np.any(m.light_castshadow)
    assert m.vis.global_.offwidth >= 96 and m.vis.global_.offheight >= 64
    assert m.cam("left").id >= 0 and m.cam("right").id >= 0
    for a in world.actors:
        assert m.body_mocapid[a.body_id] >= 0 and m.body_rootid[a.body_id] == a.body_id
        lo, hi = _geom_extent_in_body(m, a.body_id)
        half = np.array(a.dims) / 2
        np.testing.assert_allclose(lo, -half, atol=1e-6, err_msg=f"{name} {a.cls} {a.track_id}")
        np.testing.assert_allclose(hi, half, atol=1e-6, err_msg=f"{name} {a.cls} {a.track_id}")
    classes = {a.cls for a in world.actors}
    assert "car" in classes
    if name == "static":
        assert all(a.parked for a in world.actors)
    else:
        assert not all(a.parked for a in world.actors)


def test_vehicle_paint_is_not_stretched(monkeypatch):
    """A checkerboard as the paint shows square cells on a car's side: MuJoCo stretches a texture over each
    face of a box primitive (7:1 on a 4.2 x 0.6 m side), so painted boxes are meshes with metric texture
    coordinates. Measured as the balance of horizontal and vertical gradient energy inside the body box."""
    def checker(rng, size, rich=True, side_m=2.0):
        cell = (np.arange(size) // 8) % 2
        return np.repeat(((cell[:, None] ^ cell[None, :]) * 200 + 30).astype(np.uint8)[..., None], 3, axis=2)

    monkeypatch.setattr("sim.textures.vehicle_paint", checker)
    world = build_world(load_scenario("traffic", ["frames=2", "image_size=320x240", "view_ahead=60"]))
    world.set_time(0.0)
    renderer = mujoco.Renderer(world.model, 240, 320)
    cam = mujoco.MjvCamera()
    cam.type, cam.distance, cam.elevation = mujoco.mjtCamera.mjCAMERA_FREE, 5.0, 0.0
    cars = [a for a in world.actors if a.cls == "car"][:3]
    assert len(cars) == 3
    for car in cars:
        R = world.data.xmat[car.body_id].reshape(3, 3)
        cam.lookat[:] = world.data.xpos[car.body_id]
        cam.azimuth = np.degrees(np.arctan2(R[1, 0], R[0, 0])) + 90.0  # looking at the car's right side
        renderer.disable_segmentation_rendering()
        renderer.update_scene(world.data, cam)
        gray = cv2.cvtColor(renderer.render(), cv2.COLOR_RGB2GRAY).astype(np.float32)
        renderer.enable_segmentation_rendering()
        renderer.update_scene(world.data, cam)
        seg = renderer.render()
        body_box = np.flatnonzero(world.model.geom_bodyid == car.body_id)[0]  # sill to belt line, painted
        inside = cv2.erode(((seg[..., 0] == body_box) & (seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM)).astype(np.uint8),
                           np.ones((9, 9), np.uint8)).astype(bool)
        assert inside.sum() > 2000
        gx, gy = cv2.Sobel(gray, cv2.CV_32F, 1, 0)[inside], cv2.Sobel(gray, cv2.CV_32F, 0, 1)[inside]
        assert 0.7 < np.sum(gx ** 2) / np.sum(gy ** 2) < 1.4, car.track_id
    renderer.close()


def test_set_time_moves_actors_and_matches_states(traffic):
    w = traffic
    states0 = w.actor_states(0.0)
    states1 = w.actor_states(1.0)
    moving = [i for i, a in enumerate(w.actors) if not a.parked]
    assert moving
    for i in moving:
        assert np.linalg.norm(states1[i][0][:3, 3] - states0[i][0][:3, 3]) > 0.05
    w.set_time(1.0)
    for a, (T_m_o, _, _) in zip(w.actors, states1):
        mid = w.model.body_mocapid[a.body_id]
        np.testing.assert_allclose(w.data.mocap_pos[mid], T_m_o[:3, 3], atol=1e-12)
        np.testing.assert_allclose(w.data.xmat[a.body_id].reshape(3, 3), T_m_o[:3, :3], atol=1e-9)
    # velocities are the time derivative of the poses (also between frames)
    t, h = 0.55, 1e-3
    sa, sb, s0 = w.actor_states(t + h), w.actor_states(t - h), w.actor_states(t)
    for i in moving:
        v_fd = (sa[i][0][:3, 3] - sb[i][0][:3, 3]) / (2 * h)
        np.testing.assert_allclose(s0[i][1], v_fd, atol=1e-4)


def test_ego_camera_pose_matches_mujoco(traffic):
    w = traffic
    for t in (0.0, 0.7, 1.1):
        w.set_time(t)
        T_m_c = w.ego_T_m_c(t)
        cid = w.model.cam("left").id
        np.testing.assert_allclose(T_m_c[:3, 3], w.data.cam_xpos[cid], atol=1e-9)
        np.testing.assert_allclose(T_m_c[:3, :3], w.data.cam_xmat[cid].reshape(3, 3) @ np.diag([1, -1, -1]),
                                   atol=1e-9)
        rid = w.model.cam("right").id
        right_in_left = T_m_c[:3, :3].T @ (w.data.cam_xpos[rid] - T_m_c[:3, 3])
        np.testing.assert_allclose(right_in_left, [w.cfg.baseline, 0, 0], atol=1e-9)
    assert w.ego_T_m_c(1.1)[0, 3] > w.ego_T_m_c(0.0)[0, 3] + 5.0  # drives forward at ~8 m/s


def _poses(world, t):
    return np.array([T for T, _, _ in world.actor_states(t)])


def test_determinism_and_seed():
    cfg = ["frames=5", "image_size=64x48", "texture_px=32", "view_ahead=40"]
    a = build_world(load_scenario("traffic", cfg + ["seed=4"]))
    b = build_world(load_scenario("traffic", cfg + ["seed=4"]))
    c = build_world(load_scenario("traffic", cfg + ["seed=5"]))
    assert [x.cls for x in a.actors] == [x.cls for x in b.actors]
    np.testing.assert_array_equal(_poses(a, 0.3), _poses(b, 0.3))
    np.testing.assert_array_equal(a.model.tex_data, b.model.tex_data)
    np.testing.assert_array_equal(a.model.geom_pos, b.model.geom_pos)
    assert a.model.tex_data.shape != c.model.tex_data.shape or np.any(a.model.tex_data != c.model.tex_data)
    pa, pc = _poses(a, 0.3), _poses(c, 0.3)
    assert pa.shape != pc.shape or not np.allclose(pa, pc)


def test_static_scenario_has_zero_velocities():
    w = build_world(load_scenario("static", SMALL))
    for t in (0.0, 0.5, 1.1):
        for _, v, om in w.actor_states(t):
            assert np.all(v == 0) and np.all(om == 0)
    assert w.ego_T_m_c(1.1)[0, 3] > w.ego_T_m_c(0.0)[0, 3] + 5.0


def _mean_speed(world):
    speeds = [np.linalg.norm(v) for k in range(world.cfg.frames)
              for (_, v, _), a in zip(world.actor_states(k / world.cfg.fps), world.actors) if not a.parked]
    return float(np.mean(speeds))


@pytest.mark.parametrize("name", ["traffic", "crossing"])
def test_object_speed_raises_speeds(name):
    slow = build_world(load_scenario(name, SMALL + ["object_speed=0.7", "frames=30"]))
    fast = build_world(load_scenario(name, SMALL + ["object_speed=1.6", "frames=30"]))
    assert _mean_speed(fast) > 1.5 * _mean_speed(slow)


def test_intrinsics_rule_from_rendered_depth():
    """fx = fy = (H/2)/tan(fovy/2), cx = (W-1)/2, cy = (H-1)/2: fitted from rendered metric depth of the
    road plane (z = 0, gives fy and cy) and of street-facing facades (planes y = const, give fx and cx)."""
    cfg = load_scenario("static", ["frames=1", "image_size=160x120", "texture_px=32", "view_ahead=40",
                                   "n_vehicles=0", "n_pedestrians=0", "occlusion=0", "curve_deg=0"])
    w = build_world(cfg)
    fx, fy, cx, cy = camera_intrinsics(cfg)
    W, H = cfg.image_size
    assert fx == fy == pytest.approx((H / 2) / np.tan(np.radians(cfg.fovy_deg) / 2))
    assert (cx, cy) == ((W - 1) / 2, (H - 1) / 2)
    w.set_time(0.0)
    r = mujoco.Renderer(w.model, H, W)
    r.update_scene(w.data, "left")
    r.enable_depth_rendering()
    depth = r.render().astype(np.float64)
    r.disable_depth_rendering()
    r.enable_segmentation_rendering()
    seg = r.render()[..., 0]
    r.close()
    m = w.model
    v, u = np.mgrid[0:H, 0:W]
    T_m_c = w.ego_T_m_c(0.0)
    names = [m.geom(g).name for g in range(m.ngeom)]
    road = np.isin(seg, [g for g, n in enumerate(names) if n.startswith("road")])
    road &= depth < 60
    assert road.sum() > 200
    # road plane: v = cy + fy * cam_height / Z
    A = np.column_stack([np.ones(road.sum()), cfg.cam_height / depth[road]])
    cy_fit, fy_fit = np.linalg.lstsq(A, v[road], rcond=None)[0]
    assert abs(cy_fit - cy) < 0.1 and abs(fy_fit / fy - 1) < 1e-3
    # facades on the right side: plane y_m = y_face, in the camera X_c = -(y_face - y_cam) = d
    fac = [g for g, n in enumerate(names) if n.startswith("building-1_")]  # right side, street along +x
    assert fac
    us, zs, ds = [], [], []
    for g in fac:
        mask = (seg == g) & (depth < 80)
        y_face = m.geom_pos[g, 1] + m.geom_size[g, 1]
        d = T_m_c[1, 3] - y_face  # metres to the right of the camera
        X = (u[mask] - cx) * depth[mask] / fx  # nominal backprojection, only to select the street face
        keep = np.abs(X - d) < 0.3
        us.append(u[mask][keep]), zs.append(depth[mask][keep]), ds.append(np.full(keep.sum(), d))
    us, zs, ds = map(np.concatenate, (us, zs, ds))
    assert len(us) > 200
    A = np.column_stack([np.ones(len(us)), ds / zs])
    inliers = np.ones(len(us), bool)
    for tol in (1.0, 0.25, 0.05):  # trim pixels of the buildings' end faces seen near their corners
        cx_fit, fx_fit = np.linalg.lstsq(A[inliers], us[inliers], rcond=None)[0]
        inliers = np.abs(A @ (cx_fit, fx_fit) - us) < tol
    assert inliers.mean() > 0.7
    cx_fit, fx_fit = np.linalg.lstsq(A[inliers], us[inliers], rcond=None)[0]
    assert abs(cx_fit - cx) < 0.1 and abs(fx_fit / fx - 1) < 1e-3


def test_fx_overrides_fovy():
    cfg = load_scenario("traffic", ["image_size=1242x375", "fx=718.856"])
    fx, fy, cx, cy = camera_intrinsics(cfg)
    assert fx == pytest.approx(718.856) and fy == pytest.approx(718.856)
    assert (cx, cy) == (620.5, 187.0)


@pytest.mark.parametrize("name,knobs", [
    ("traffic", ["n_vehicles=0", "n_pedestrians=0"]),
    ("crossing", ["lanes_per_direction=1", "object_speed=0", "ego_speed=0"]),
    ("following", ["lanes_per_direction=3", "parked_fraction=0", "occlusion=1", "fps=30", "frames=1"]),
    ("static", ["texture=poor", "depth=false", "fx=80", "n_vehicles=60"]),
])
def test_knob_extremes_build_and_move(name, knobs):
    w = build_world(load_scenario(name, ["image_size=64x48", "texture_px=32", "view_ahead=40", "frames=8"] + knobs))
    w.set_time(0.35)  # between frames: evaluated, not looked up
    for a, (T_m_o, v, om) in zip(w.actors, w.actor_states(0.35)):
        np.testing.assert_allclose(w.data.xpos[a.body_id], T_m_o[:3, 3], atol=1e-9)
        assert np.all(np.isfinite(v)) and np.all(np.isfinite(om))
    if "object_speed=0" in knobs:
        assert all(a.parked for a in w.actors)
    if "n_vehicles=0" in knobs:
        assert w.actors == []


def test_motion_primitives_are_exact():
    from sim.motion import Path, SpeedProfile, Trajectory

    prof = SpeedProfile.of([(0.0, 10.0), (2.0, 0.0), (4.0, 0.0), (6.0, 5.0)])
    t = np.linspace(-1.0, 8.0, 9001)
    np.testing.assert_allclose(np.gradient(prof.distance(t), t)[1:-1], prof.speed(t)[1:-1], atol=1e-4)
    assert prof.distance(6.0) == pytest.approx(10.0 + 0.0 + 5.0)  # smoothstep ramps average the speeds
    turn = Path.build(0.0, 0.0, 0.0, [("straight", 5.0), ("turn", 12.0, np.pi / 2), ("straight", 5.0)])
    assert turn.heading[-1] == pytest.approx(np.pi / 2, abs=1e-9)
    shift = Path.build(0.0, -1.75, 0.0, [("straight", 5.0), ("shift", 40.0, 3.5), ("straight", 5.0)])
    assert shift.y[-1] == pytest.approx(1.75, abs=1e-3) and shift.heading[-1] == pytest.approx(0.0, abs=1e-9)
    lead = Trajectory(turn, prof)
    follower = lead.follower(delay=1.0, gap=8.0)
    s_lead, s_f = lead.arc(t), follower.arc(t)
    np.testing.assert_allclose(s_f[1000:], s_lead[:-1000] - 8.0, atol=1e-9)  # Newell: s_f(t) = s(t - 1) - 8
    vx, vy, wz = lead.velocity(np.array([3.0, 5.5]))
    # |v| equals the profile speed up to the path interpolation (arc length exact to ~1e-5 relative)
    np.testing.assert_allclose(np.hypot(vx, vy), prof.speed(np.array([3.0, 5.5])), rtol=1e-4, atol=1e-9)


def test_turning_profile_holds_the_turn_speed_over_the_turn():
    from sim.motion import turning_profile

    prof = turning_profile(v_cruise=10.0, approach=40.0, turn_length=12.0, v_turn=3.4)
    t = np.linspace(-10.0, 30.0, 400001)
    s = prof.distance(t)
    in_turn = (s >= 40.0) & (s <= 52.0)
    np.testing.assert_allclose(prof.speed(t[in_turn]), 3.4, atol=1e-3)
    assert prof.speed(t[0]) == 10.0 and prof.speed(t[-1]) == 10.0
    assert np.all(np.abs(np.diff(prof.speed(t))) * 1e4 < 3.0 * 1.5 + 1e-6)  # ramps as stop_and_go_profile's
    assert turning_profile(3.0, 40.0, 12.0, 3.4).speed(5.0) == 3.0  # slower than the turn speed: unchanged


@pytest.mark.parametrize("accel", [3.0, 1.5])
def test_turning_vehicles_keep_their_lateral_acceleration(accel):
    """crossing's right turns: |v| * yaw rate <= turn_lateral_accel (before world 3 they turned at up to 2.5 rad/s,
    24 m/s^2), reached at the turn's peak curvature; a follower of a turning vehicle turns as slowly."""
    from sim.motion import plan_scenario

    peaks = []
    for seed in range(4):
        cfg = load_scenario("crossing", [f"seed={seed}", "frames=150", f"turn_lateral_accel={accel}"])
        plan = plan_scenario(cfg, np.random.SeedSequence(seed).spawn(3)[0])
        t = np.arange(0.0, cfg.duration, 0.01)
        for actor in plan.actors:
            path = actor.trajectory.path
            if abs(abs(path.heading[-1] - path.heading[0]) - np.pi / 2) < 1e-6:
                vx, vy, yaw_rate = actor.trajectory.velocity(t)
                peaks.append(np.max(np.hypot(vx, vy) * np.abs(yaw_rate)))
    assert len(peaks) >= 3
    assert max(peaks) <= accel * 1.01 and np.median(peaks) >= accel * 0.95


def test_street_bend_turns_the_ego():
    w = build_world(load_scenario("following", ["frames=150", "image_size=64x48", "texture_px=32",
                                                "curve_deg=15", "curve_start=30"]))
    R0, R1 = w.ego_T_m_c(0.0)[:3, :3], w.ego_T_m_c(14.9)[:3, :3]
    yaw_change = np.degrees(np.arccos(np.clip((np.trace(R0.T @ R1) - 1) / 2, -1, 1)))
    assert 3.0 < yaw_change <= 15.0 + 1e-6
    w.set_time(14.9)
    cid = w.model.cam("left").id
    np.testing.assert_allclose(w.ego_T_m_c(14.9)[:3, :3], w.data.cam_xmat[cid].reshape(3, 3) @ np.diag([1, -1, -1]),
                               atol=1e-9)
