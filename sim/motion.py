"""Kinematic trajectories: arc-length paths (curvature profiles) timed by smooth speed profiles.

A `Trajectory` gives the planar pose (x, y, yaw) of an object's box centre at any time t:
`s(t) = s0 + S(t - tau)` where `S` is the exact integral of a `SpeedProfile` (constant speeds
joined by smoothstep ramps, so acceleration is continuous) and the `Path` maps arc length to
(x, y, heading). Turns and lane changes are curvature profiles along the path (yaw rate =
curvature * speed). A follower that copies a leader with a time delay and a gap (Newell's
car-following model) is the same path and profile with a larger `tau` and a smaller `s0`, so
platoons never collide. Velocities are central differences (h = 1e-4 s) of the closed form.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

_DT_DIFF = 1e-4  # s, central-difference step for velocities of the closed-form poses
_DS = 0.05  # m, arc-length grid of paths


@dataclass(frozen=True)
class SpeedProfile:
    """Speed through knots (t_k, v_k): constant outside, smoothstep 3x^2-2x^3 between knots."""

    t_knots: np.ndarray
    v_knots: np.ndarray

    @staticmethod
    def constant(v: float) -> "SpeedProfile":
        return SpeedProfile(np.array([0.0, 1.0]), np.array([v, v], float))

    @staticmethod
    def of(knots: list[tuple[float, float]]) -> "SpeedProfile":
        """From [(t, v), ...] with increasing t (a single knot means constant speed)."""
        t = np.array([k[0] for k in knots], float)
        v = np.array([k[1] for k in knots], float)
        if len(t) == 1:
            t, v = np.array([t[0], t[0] + 1.0]), np.array([v[0], v[0]])
        return SpeedProfile(t, v)

    def scaled(self, k: float) -> "SpeedProfile":
        return SpeedProfile(self.t_knots, self.v_knots * k)

    def _locate(self, t: np.ndarray):
        tk = self.t_knots
        i = np.clip(np.searchsorted(tk, t, side="right") - 1, 0, len(tk) - 2)
        h = tk[i + 1] - tk[i]
        x = np.clip((t - tk[i]) / h, 0.0, 1.0)
        return i, h, x

    def speed(self, t) -> np.ndarray:
        t = np.asarray(t, float)
        i, _, x = self._locate(t)
        v0, v1 = self.v_knots[i], self.v_knots[i + 1]
        return v0 + (v1 - v0) * x * x * (3.0 - 2.0 * x)

    def distance(self, t) -> np.ndarray:
        """Exact integral of the speed from 0 to t (negative for t < 0)."""
        return self._antiderivative(np.asarray(t, float)) - self._antiderivative(np.zeros(1))[0]

    def _antiderivative(self, t: np.ndarray) -> np.ndarray:
        tk, vk = self.t_knots, self.v_knots
        seg = np.diff(tk) * 0.5 * (vk[:-1] + vk[1:])
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        i, h, x = self._locate(t)
        inside = cum[i] + h * (vk[i] * x + (vk[i + 1] - vk[i]) * (x ** 3 - 0.5 * x ** 4))
        before = vk[0] * np.minimum(t - tk[0], 0.0)
        after = vk[-1] * np.maximum(t - tk[-1], 0.0)
        return inside + before + after


@dataclass(frozen=True)
class Path:
    """Planar path by arc length s: grid of (x, y, heading); straight extension beyond both ends."""

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray

    @staticmethod
    def build(x0: float, y0: float, heading0: float, segments: list[tuple]) -> "Path":
        """Segments: ("straight", L), ("turn", L, angle) with curvature k0*sin^2(pi u/L) turning by
        `angle`, ("shift", L, dy) a lane change by dy to the left of the heading (curvature doublet)."""
        kappa = [np.zeros(1)]
        for seg in segments:
            n = max(2, int(round(seg[1] / _DS)))
            u = (np.arange(n) + 0.5) / n
            if seg[0] == "straight":
                kappa.append(np.zeros(n))
            elif seg[0] == "turn":
                kappa.append(2.0 * seg[2] / seg[1] * np.sin(np.pi * u) ** 2)
            elif seg[0] == "shift":
                kappa.append(_shift_curvature(seg[1], seg[2], n))
            else:
                raise ValueError(f"unknown path segment {seg[0]!r}")
        k = np.concatenate(kappa)
        return _integrate(x0, y0, heading0, k)

    def pose(self, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, heading) at arc lengths s (cubic Hermite in x, y with the exact unit tangents)."""
        s = np.asarray(s, float)
        sc = np.clip(s, 0.0, self.s[-1])
        i = np.clip(np.searchsorted(self.s, sc, side="right") - 1, 0, len(self.s) - 2)
        ds = self.s[i + 1] - self.s[i]
        u = (sc - self.s[i]) / ds
        h00, h10 = 2 * u ** 3 - 3 * u ** 2 + 1, u ** 3 - 2 * u ** 2 + u
        h01, h11 = -2 * u ** 3 + 3 * u ** 2, u ** 3 - u ** 2
        c0, s0 = np.cos(self.heading[i]), np.sin(self.heading[i])
        c1, s1 = np.cos(self.heading[i + 1]), np.sin(self.heading[i + 1])
        x = h00 * self.x[i] + h10 * ds * c0 + h01 * self.x[i + 1] + h11 * ds * c1
        y = h00 * self.y[i] + h10 * ds * s0 + h01 * self.y[i + 1] + h11 * ds * s1
        hd = self.heading[i] + u * (self.heading[i + 1] - self.heading[i])
        extra = s - sc  # straight continuation outside [0, length]
        return x + extra * np.cos(hd), y + extra * np.sin(hd), hd


def _integrate(x0: float, y0: float, heading0: float, kappa: np.ndarray) -> Path:
    n = len(kappa)
    s = np.arange(n + 1) * _DS
    k = np.concatenate([kappa, kappa[-1:]])
    heading = heading0 + np.concatenate([[0.0], np.cumsum(0.5 * (k[:-1] + k[1:]) * _DS)])
    mid = heading[:-1] + 0.5 * np.diff(heading)  # midpoint rule on each step
    x = x0 + np.concatenate([[0.0], np.cumsum(np.cos(mid) * _DS)])
    y = y0 + np.concatenate([[0.0], np.cumsum(np.sin(mid) * _DS)])
    return Path(s, x, y, heading)


def _shift_curvature(length: float, dy: float, n: int) -> np.ndarray:
    """Curvature doublet A*sin(2 pi u) over `length` whose lateral displacement is dy (2 secant steps)."""
    u = (np.arange(n) + 0.5) / n
    shape = np.sin(2 * np.pi * u)
    amp = 2 * np.pi * dy / length ** 2
    for _ in range(3):
        p = _integrate(0.0, 0.0, 0.0, amp * shape)
        got = p.y[-1]
        if abs(got) < 1e-12:
            break
        amp *= dy / got
    return amp * shape


@dataclass(frozen=True)
class Trajectory:
    """Planar pose of a box centre over time: path(s0 + S(t - tau)), yaw = heading + yaw_offset."""

    path: Path
    speed: SpeedProfile
    s0: float = 0.0
    tau: float = 0.0
    yaw_offset: float = 0.0

    def arc(self, t) -> np.ndarray:
        return self.s0 + self.speed.distance(np.asarray(t, float) - self.tau)

    def pose(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, yaw) arrays at times t."""
        x, y, hd = self.path.pose(self.arc(t))
        return x, y, hd + self.yaw_offset

    def velocity(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vx, vy, yaw_rate) at times t, central differences of `pose`."""
        t = np.asarray(t, float)
        xa, ya, qa = self.pose(t + _DT_DIFF)
        xb, yb, qb = self.pose(t - _DT_DIFF)
        k = 0.5 / _DT_DIFF
        return (xa - xb) * k, (ya - yb) * k, (qa - qb) * k

    def follower(self, delay: float, gap: float) -> "Trajectory":
        """Newell follower on the same path: s_f(t) = s(t - delay) - gap."""
        return Trajectory(self.path, self.speed, self.s0 - gap, self.tau + delay, self.yaw_offset)

    def delayed(self, headway: float) -> "Trajectory":
        """The same motion `headway` seconds later, s_f(t) = s(t - headway): a follower that slows where the
        leader slowed (a Newell follower would slow `gap` metres too late)."""
        return Trajectory(self.path, self.speed, self.s0, self.tau + headway, self.yaw_offset)

    def is_static(self) -> bool:
        return bool(np.all(self.speed.v_knots == 0.0))


def static_trajectory(x: float, y: float, yaw: float) -> Trajectory:
    """An object that never moves."""
    return Trajectory(Path.build(x, y, yaw, [("straight", 1.0)]), SpeedProfile.constant(0.0))


# Speed ramps of the profiles below: mean braking / accelerating rates (m/s^2; a smoothstep peaks at 1.5x the
# mean) and the shortest ramp (s).
_BRAKE_RATE, _ACCEL_RATE, _MIN_RAMP_S = 3.0, 2.5, 1.5


def stop_and_go_profile(rng: np.random.Generator, v_nominal: float, t_end: float, stop_prob: float = 0.3,
                        variation: float = 0.2) -> SpeedProfile:
    """Speeds drawn around v_nominal at knots every 2.5-5 s, with occasional stops of 1.5-3 s
    (braking/accelerating at <= ~3 m/s^2)."""
    knots = [(-5.0, v_nominal * rng.uniform(1 - variation, 1 + variation))]
    t = 0.0
    while t < t_end + 5.0:
        v_prev = knots[-1][1]
        if rng.random() < stop_prob and v_nominal > 0:
            ramp = max(_MIN_RAMP_S, v_prev / _BRAKE_RATE)
            knots.append((t + ramp, 0.0))
            t += ramp + rng.uniform(1.5, 3.0)
            knots.append((t, 0.0))
            v = v_nominal * rng.uniform(1 - variation, 1 + variation)
            t += max(_MIN_RAMP_S, v / _ACCEL_RATE)
            knots.append((t, v))
        else:
            v = v_nominal * rng.uniform(1 - variation, 1 + variation)
            t += max(rng.uniform(2.5, 5.0), abs(v - v_prev) / _ACCEL_RATE)
            knots.append((t, v))
    return SpeedProfile.of(knots)


def turning_profile(v_cruise: float, approach: float, turn_length: float, v_turn: float) -> SpeedProfile:
    """Cruise at v_cruise, brake to v_turn so as to reach arc length `approach` (where the turn starts) at
    v_turn, hold it over the `turn_length` metres of the turn, then accelerate back to v_cruise (ramps as
    in stop_and_go_profile: _BRAKE_RATE, _ACCEL_RATE). Constant v_cruise when
    that is not faster than v_turn."""
    if v_cruise <= v_turn:
        return SpeedProfile.constant(v_cruise)
    brake = max(_MIN_RAMP_S, (v_cruise - v_turn) / _BRAKE_RATE)
    accelerate = max(_MIN_RAMP_S, (v_cruise - v_turn) / _ACCEL_RATE)
    t_turn = (approach - brake * 0.5 * (v_cruise + v_turn)) / v_cruise + brake  # distance(t_turn) = approach
    t_out = t_turn + turn_length / v_turn
    return SpeedProfile.of([(min(t_turn - brake, 0.0) - 5.0, v_cruise), (t_turn - brake, v_cruise), (t_turn, v_turn),
                            (t_out, v_turn), (t_out + accelerate, v_cruise)])


@dataclass
class Footprints:
    """Oriented 2D rectangles (half length, half width) sampled over time, for overlap rejection."""

    times: np.ndarray
    xs: list = field(default_factory=list)
    ys: list = field(default_factory=list)
    yaws: list = field(default_factory=list)
    halves: list = field(default_factory=list)

    def add(self, traj: Trajectory, length: float, width: float) -> None:
        x, y, q = traj.pose(self.times)
        self.xs.append(x), self.ys.append(y), self.yaws.append(q)
        self.halves.append((0.5 * length, 0.5 * width))

    def collides(self, traj: Trajectory, length: float, width: float, margin: float = 0.5) -> bool:
        """True if the rectangle on `traj` overlaps any stored one (grown by margin) at any sample time."""
        if not self.xs:
            return False
        x, y, q = traj.pose(self.times)
        X, Y, Q = np.array(self.xs), np.array(self.ys), np.array(self.yaws)  # (M, T)
        H = np.array(self.halves)  # (M, 2)
        hl1, hw1 = 0.5 * length + margin / 2, 0.5 * width + margin / 2
        hl2, hw2 = H[:, :1] + margin / 2, H[:, 1:] + margin / 2
        dx, dy = X - x, Y - y
        axes = [(np.cos(q), np.sin(q)), (-np.sin(q), np.cos(q)), (np.cos(Q), np.sin(Q)), (-np.sin(Q), np.cos(Q))]
        separated = np.zeros(X.shape, bool)
        for ux, uy in axes:
            r1 = hl1 * np.abs(np.cos(q) * ux + np.sin(q) * uy) + hw1 * np.abs(-np.sin(q) * ux + np.cos(q) * uy)
            r2 = hl2 * np.abs(np.cos(Q) * ux + np.sin(Q) * uy) + hw2 * np.abs(-np.sin(Q) * ux + np.cos(Q) * uy)
            separated |= np.abs(dx * ux + dy * uy) > r1 + r2
        return bool((~separated).any())


# ---------------------------------------------------------------------------------------------
# Scenario planning: where the street is, who drives where and when.

VEHICLE_DIMS = {  # (length, width, height) ranges in metres
    "car": ((3.8, 4.7), (1.7, 1.9), (1.4, 1.6)),
    "van": ((4.8, 5.4), (1.9, 2.1), (2.0, 2.5)),
    "truck": ((7.0, 9.0), (2.4, 2.55), (3.0, 3.4)),
    "pedestrian": ((0.45, 0.55), (0.55, 0.65), (1.6, 1.9)),
}
EGO_DIMS = (4.5, 1.9, 1.5)
CAMERA_FORWARD = 0.5  # m, camera ahead of the ego box centre
EGO_CLEARANCE = 3.0  # m kept free ahead of (and behind) the ego's box by every actor


@dataclass(frozen=True)
class StreetLayout:
    """Street geometry in street coordinates (x along the street, y to the left, z up, road at z = 0).

    Planning happens in street coordinates; `to_world` bends them onto the street's centreline (a
    `Path`, straight then a gentle smooth bend), so lanes, kerbs and facades follow the bend.
    """

    lane_width: float
    lanes_per_direction: int
    half_road: float  # |y| of the edge of the driving lanes
    kerb: float  # |y| of the kerb (driving lanes + parking strip)
    sidewalk_outer: float  # |y| where the sidewalk ends and buildings start
    x_lo: float
    x_hi: float
    x_int: float | None  # x of the crossing street (intersection layout) or None
    cross_half: float  # half width of the crossing street road
    centre: Path  # centreline in the MuJoCo world, arc length s = x - centre_x0
    centre_x0: float

    def to_world(self, x, y, yaw=0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Street coordinates (x, y, yaw) -> MuJoCo world (X, Y, YAW) on the ground plane."""
        cx, cy, th = self.centre.pose(np.asarray(x, float) - self.centre_x0)
        y = np.asarray(y, float)
        return cx - y * np.sin(th), cy + y * np.cos(th), np.asarray(yaw, float) + th

    def world_pose(self, traj: "Trajectory", t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, Y, YAW) in the MuJoCo world of a trajectory planned in street coordinates."""
        return self.to_world(*traj.pose(t))

    def world_velocity(self, traj: "Trajectory", t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vX, vY, yaw rate) in the MuJoCo world: central differences of `world_pose`."""
        t = np.asarray(t, float)
        xa, ya, qa = self.world_pose(traj, t + _DT_DIFF)
        xb, yb, qb = self.world_pose(traj, t - _DT_DIFF)
        k = 0.5 / _DT_DIFF
        return (xa - xb) * k, (ya - yb) * k, (qa - qb) * k

    def lane_y(self, index: int, oncoming: bool) -> float:
        """Lane centre; index 0 is the lane next to the centre line; oncoming lanes are at y > 0."""
        y = (index + 0.5) * self.lane_width
        return y if oncoming else -y

    def in_intersection(self, x: np.ndarray | float, margin: float = 0.0) -> np.ndarray | bool:
        if self.x_int is None:
            return np.zeros_like(np.asarray(x, float), bool) if np.ndim(x) else False
        return np.abs(np.asarray(x) - self.x_int) < self.cross_half + margin


@dataclass(frozen=True)
class PlannedActor:
    cls: str
    dims: tuple[float, float, float]
    trajectory: Trajectory


@dataclass(frozen=True)
class Prop:
    """Static street furniture that occludes, on the sidewalk next to the kerb: kind "tree", "pole",
    "hedge" (low long box) or "kiosk" (box), centred at (x, y) with a (length, width) footprint."""

    kind: str
    x: float
    y: float
    length: float
    width: float


@dataclass(frozen=True)
class MotionPlan:
    layout: StreetLayout
    ego: Trajectory
    actors: tuple[PlannedActor, ...]
    props: tuple[Prop, ...]


def _dims(rng: np.random.Generator, cls: str) -> tuple[float, float, float]:
    return tuple(float(rng.uniform(*r)) for r in VEHICLE_DIMS[cls])  # type: ignore[return-value]


def _ego_profile(cfg, rng: np.random.Generator, duration: float) -> SpeedProfile:
    v = cfg.ego_speed
    if cfg.layout == "following":
        return stop_and_go_profile(rng, v, duration, stop_prob=0.15, variation=0.25)
    if cfg.layout == "intersection":  # brake to a stop at the stop line, wait, go
        t_b = 0.15 * duration
        t_s = t_b + max(2.0, v / 2.5)
        t_g = t_s + min(max(2.0, 0.3 * duration), 8.0)
        return SpeedProfile.of([(t_b, v), (t_s, 0.0), (t_g, 0.0), (t_g + max(2.5, v / 2.0), v)])
    knots, t = [(0.0, v)], 0.0
    while t < duration + 3.0:
        t += rng.uniform(3.0, 5.0)
        knots.append((t, v * rng.uniform(0.9, 1.1)))
    return SpeedProfile.of(knots)


def _ego_path(cfg, rng: np.random.Generator, y0: float) -> Path:
    """Straight along +x; on the plain street with 2+ lanes, a lane change to the right and back."""
    if cfg.layout != "street" or cfg.lanes_per_direction < 2 or not cfg.ego_lane_change:
        return Path.build(0.0, y0, 0.0, [("straight", 1.0)])
    v, duration = max(cfg.ego_speed, 1.0), cfg.duration
    return Path.build(0.0, y0, 0.0, [("straight", v * duration * rng.uniform(0.1, 0.3)),
                                     ("shift", rng.uniform(35.0, 50.0), -cfg.lane_width),
                                     ("straight", v * duration * rng.uniform(0.15, 0.3)),
                                     ("shift", rng.uniform(35.0, 50.0), cfg.lane_width), ("straight", 1.0)])


def plan_scenario(cfg, seed_seq: np.random.SeedSequence) -> MotionPlan:
    """Ego route, actors with collision-free trajectories and kerbside props for `cfg`."""
    rng_ego, rng_park, rng_move, rng_ped, rng_prop = [np.random.default_rng(s) for s in seed_seq.spawn(5)]
    duration = cfg.duration
    lw, n_l = cfg.lane_width, cfg.lanes_per_direction
    ego_speed = _ego_profile(cfg, rng_ego, duration)
    ego_y = -0.5 * lw
    ego = Trajectory(_ego_path(cfg, rng_ego, ego_y), ego_speed)
    ego_end = float(ego.arc(duration))
    half_road = n_l * lw
    kerb = half_road + cfg.parking_width
    x_int = None
    cross_half = lw
    if cfg.layout == "intersection":
        x_stop = float(ego.arc(ego_speed.t_knots[2]))
        x_int = x_stop + EGO_DIMS[0] / 2 + EGO_CLEARANCE + cross_half + 4.5
    x_lo, x_hi = -40.0, max(ego_end, x_int or 0.0) + cfg.view_ahead
    curve_start = cfg.curve_start if x_int is None else max(cfg.curve_start, x_int + cross_half + 40.0)
    centre_x0 = x_lo - 100.0
    centre = Path.build(centre_x0, 0.0, 0.0, [("straight", curve_start - centre_x0),
                                              ("turn", cfg.curve_length, np.radians(cfg.curve_deg)),
                                              ("straight", 1.0)])
    layout = StreetLayout(lw, n_l, half_road, kerb, kerb + cfg.sidewalk_width, x_lo, x_hi, x_int, cross_half,
                          centre, centre_x0)
    times = np.arange(0.0, max(duration, 0.05) + 1e-9, 0.05)
    fp = Footprints(times)
    fp.add(ego, EGO_DIMS[0] + 2 * EGO_CLEARANCE, EGO_DIMS[1])
    props = _plan_props(cfg, layout, rng_prop)
    for p in props:
        fp.add(static_trajectory(p.x, p.y, 0.0), p.length, p.width)
    actors: list[PlannedActor] = []

    def inside(traj: Trajectory) -> bool:
        """Within the modelled streets at every sample time (never drives into the end walls)."""
        x, y, _ = traj.pose(times)
        ok = (x > layout.x_lo - 25.0) & (x < layout.x_hi + 25.0) & (np.abs(y) < layout.sidewalk_outer)
        if layout.x_int is not None:
            ok |= (np.abs(x - layout.x_int) < layout.cross_half) & (np.abs(y) < layout.kerb + 90.0)
        return bool(ok.all())

    def try_add(make, tries: int = 40, margin: float = 0.5, valid=None) -> PlannedActor | None:
        """Draw candidates from `make()` until one is `valid`, stays in the streets and overlaps nothing
        planned so far; None if all fail."""
        for _ in range(tries):
            cls, dims, traj = make()
            if (valid is None or valid(traj)) and inside(traj) and not fp.collides(traj, dims[0], dims[1], margin):
                fp.add(traj, dims[0], dims[1])
                actors.append(PlannedActor(cls, dims, traj))
                return actors[-1]
        return None

    n_parked = int(round(cfg.parked_fraction * cfg.n_vehicles))
    _plan_moving(cfg, layout, rng_move, ego, ego_end, cfg.n_vehicles - n_parked, try_add)
    parked = _plan_parked(cfg, layout, rng_park, ego_end, n_parked, try_add)
    _plan_pedestrians(cfg, layout, rng_ped, ego_end, parked, props, try_add)
    return MotionPlan(layout, ego, tuple(actors), tuple(props))


def _plan_props(cfg, layout: StreetLayout, rng: np.random.Generator) -> list[Prop]:
    """Kerbside furniture; `occlusion` shortens the spacing and favours hedges and kiosks (which hide
    parked vehicles and pedestrians) over thin poles and trees."""
    occ = cfg.occlusion
    spacing = 30.0 - 20.0 * occ
    p_kind = np.array([0.55 - 0.25 * occ, 0.45 - 0.25 * occ, 0.35 * occ, 0.15 * occ])
    p_kind /= p_kind.sum()
    props = []
    for side in (-1.0, 1.0):
        x = layout.x_lo + rng.uniform(0, spacing)
        while x < layout.x_hi:
            kind = str(rng.choice(["tree", "pole", "hedge", "kiosk"], p=p_kind))
            length, width = {"tree": (0.6, 0.6), "pole": (0.4, 0.4), "hedge": (rng.uniform(2.5, 6.0), 0.8),
                             "kiosk": (rng.uniform(1.4, 2.2), rng.uniform(1.2, 1.6))}[kind]
            if not layout.in_intersection(x, cfg.sidewalk_width + length / 2 + 1.0):
                y = side * (layout.kerb + 0.3 + width / 2)
                props.append(Prop(kind, float(x), float(y), float(length), float(width)))
            x += length + spacing * rng.uniform(0.6, 1.4)
    return props


def _plan_parked(cfg, layout: StreetLayout, rng: np.random.Generator, ego_end: float, n: int,
                 try_add) -> list[PlannedActor]:
    """Parked vehicles in the parking strips; returns those placed.

    `occlusion` (occ) packs them into the stretch the camera sees (x from -10 + 15*occ to
    ego_end + 70 - 40*occ), continues the last row with probability occ (0.8-2.5 m behind or ahead
    of the last one parked, so each hides part of the next) and raises the share of vans and trucks;
    any other vehicle keeps (1 - occ) * 12 m from those parked on its side.
    """
    occ = cfg.occlusion
    p_large = 0.15 + 0.5 * occ
    y_strip = layout.half_road + 0.5 * cfg.parking_width
    x_lo, x_hi = -10.0 + 15.0 * occ, min(layout.x_hi - 10.0, ego_end + 70.0 - 40.0 * occ)
    spacing = 12.0 * (1.0 - occ)
    parked: list[PlannedActor] = []

    def crowded(x: float, length: float, side: float) -> bool:
        for p in parked:  # over parked vehicles (a few dozen at most)
            x_p, y_p, _ = p.trajectory.pose(0.0)
            if np.sign(y_p) == side and abs(float(x_p) - x) - 0.5 * (p.dims[0] + length) < spacing:
                return True
        return False

    def make():
        cls = "car" if rng.random() > p_large else ("van" if rng.random() < 0.65 else "truck")
        dims = _dims(rng, cls)
        row = parked and rng.random() < occ
        if row:  # continue the last row, mostly away from the ego
            nb = parked[-1]
            x_nb, y_nb, _ = nb.trajectory.pose(0.0)
            side = float(np.sign(y_nb))
            step = 0.5 * (nb.dims[0] + dims[0]) + rng.uniform(0.8, 2.5)
            x = float(x_nb) + (step if rng.random() < 0.8 else -step)
            row = x_lo <= x <= x_hi
        if not row:
            side = -1.0 if rng.random() < 0.5 else 1.0
            if layout.x_int is not None and rng.random() < occ:  # at the corners, hiding the crossing
                near = layout.cross_half + cfg.sidewalk_width + 0.5 * dims[0] + 2.5
                x = layout.x_int + rng.choice([-1.0, 1.0]) * rng.uniform(near, near + 20.0)
            else:
                x = rng.uniform(x_lo, x_hi)
            if crowded(x, dims[0], side):
                x = layout.x_hi + 1e3  # rejected below
        if layout.in_intersection(x, cfg.sidewalk_width + dims[0] / 2 + 2.0):
            x = layout.x_hi + 1e3  # off the street: rejected below
        y = side * (y_strip + rng.uniform(-0.15, 0.15) - 0.5 * max(0.0, dims[1] - 2.0))
        yaw = (0.0 if side < 0 else np.pi) + rng.uniform(-0.04, 0.04)
        return cls, dims, static_trajectory(x, y, yaw)

    for _ in range(n):
        added = try_add(make, margin=0.4, valid=lambda traj: float(traj.pose(0.0)[0]) < layout.x_hi)
        if added is not None:
            parked.append(added)
    return parked


def _moving_class(rng: np.random.Generator) -> str:
    r = rng.random()
    return "car" if r < 0.7 else ("van" if r < 0.9 else "truck")


def _plan_moving(cfg, layout: StreetLayout, rng: np.random.Generator, ego: Trajectory, ego_end: float,
                 n: int, try_add) -> None:
    """Moving vehicles: lane platoons (Newell followers), ego-lane leaders, crossing and turning traffic."""
    n_cross = 0
    if cfg.layout == "intersection":
        n_cross = int(round(0.65 * n))
        _plan_cross_traffic(cfg, layout, rng, n_cross, try_add)
    n_follow = 0
    if cfg.layout == "following":
        n_follow = int(round(0.6 * n))
        _plan_followers(cfg, layout, rng, ego, n_follow, try_add)
    lanes = [(i, False) for i in range(layout.lanes_per_direction)] + \
            [(i, True) for i in range(layout.lanes_per_direction)]
    weights = np.ones(len(lanes))
    nearby = [j for j, (i, onc) in enumerate(lanes) if (i == 1 and not onc) or (i == 0 and onc)]
    weights[nearby] = 0.25 + 2.75 * cfg.occlusion  # occlusion brings traffic into the lanes beside the ego
    if cfg.layout != "street":  # ego lane is reserved for followers / the stop line
        weights[0] = 0.0
    weights /= weights.sum()
    chosen = rng.choice(len(lanes), size=max(0, n - n_cross - n_follow), p=weights)
    for lane_idx in range(len(lanes)):
        count = int((chosen == lane_idx).sum())
        if count:
            _plan_lane(cfg, layout, rng, ego_end, lanes[lane_idx], count, try_add)


def _plan_lane(cfg, layout: StreetLayout, rng: np.random.Generator, ego_end: float, lane: tuple[int, bool],
               count: int, try_add) -> None:
    index, oncoming = lane
    duration, k, occ = cfg.duration, cfg.object_speed, cfg.occlusion
    heading = np.pi if oncoming else 0.0
    y = layout.lane_y(index, oncoming)
    ego_lane = index == 0 and not oncoming
    last: list[PlannedActor] = []  # the vehicle the next one follows

    def make_leader():
        cls = _moving_class(rng)
        dims = _dims(rng, cls)
        if ego_lane:  # ahead of the ego and faster, never stopping
            x0 = rng.uniform(12.0, 40.0 - 25.0 * occ)
            prof = stop_and_go_profile(rng, max(cfg.ego_speed * 1.3, 9.0) * max(k, 1.0), duration, 0.0, 0.1)
        elif oncoming:
            lo = 0.3 * ego_end + 30.0 - 20.0 * occ
            x0 = rng.uniform(lo, max(lo, layout.x_hi - 60.0 * occ))
            prof = stop_and_go_profile(rng, rng.uniform(7.0, 13.0) * k, duration)
        else:  # occlusion: a platoon ahead whose tail is near the ego, at about its speed, stays in view
            x0 = rng.uniform(-15.0 + 35.0 * occ, ego_end + 60.0 - 10.0 * occ)
            v = (1.0 - occ) * rng.uniform(6.0, 13.0) + occ * cfg.ego_speed * rng.uniform(0.85, 1.15)
            prof = stop_and_go_profile(rng, v * k, duration, 0.3 * (1.0 - occ))
        segs: list[tuple] = [("straight", 1.0)]
        if index > 0 and rng.random() < 0.3:  # lane change towards the centre line
            segs = [("straight", rng.uniform(10.0, 60.0)), ("shift", rng.uniform(30.0, 45.0), layout.lane_width),
                    ("straight", 1.0)]
        path = Path.build(x0, y, heading, segs)
        return cls, dims, Trajectory(path, prof)

    def make_follower():
        cls = _moving_class(rng)
        dims = _dims(rng, cls)
        # occlusion closes the gaps (1.5-4 m at occ = 1, 13.5-34 m at occ = 0: few overlaps in the image)
        gap = 0.5 * (last[0].dims[0] + dims[0]) + rng.uniform(1.5, 4.0) + (1.0 - occ) ** 2 * rng.uniform(12.0, 30.0)
        return cls, dims, last[0].trajectory.follower(rng.uniform(0.8, 1.8), gap)

    for _ in range(count):
        added = try_add(make_follower if last else make_leader)
        if added is not None:
            last[:] = [added]


def _plan_followers(cfg, layout: StreetLayout, rng: np.random.Generator, ego: Trajectory, n: int,
                    try_add) -> None:
    """`following`: a platoon ahead in the ego lane driving the ego's speed profile earlier (Newell,
    never slower than the ego) and vehicles in the next lane at a similar speed."""
    k = cfg.object_speed
    dense = 1.0 - 0.7 * cfg.occlusion  # occlusion shortens the gaps and lengthens the ego-lane platoon
    n_lane = n if cfg.lanes_per_direction == 1 else min(1 + int(round(2 * cfg.occlusion)), n)
    ahead = [ego]
    front = EGO_DIMS[0]
    lead_is_ego = [True]
    for _ in range(n_lane):
        def make():
            cls = _moving_class(rng)
            dims = _dims(rng, cls)
            clearance = EGO_CLEARANCE + 0.5 if lead_is_ego[0] else 0.0
            gap = 0.5 * (front + dims[0]) + clearance + dense * rng.uniform(2.0, 6.0)
            lead = ahead[-1]
            return cls, dims, Trajectory(lead.path, ego.speed.scaled(max(k, 1.0)), lead.s0 + gap,
                                         lead.tau - rng.uniform(0.3, 0.8))
        added = try_add(make)
        if added is not None:
            ahead.append(added.trajectory)
            front = added.dims[0]
            lead_is_ego[0] = False
    if cfg.lanes_per_direction == 1:
        return
    y = layout.lane_y(1, False)
    last: list[PlannedActor] = []
    for _ in range(n - n_lane):
        def make():
            cls = _moving_class(rng)
            dims = _dims(rng, cls)
            if last:
                gap = 0.5 * (last[0].dims[0] + dims[0]) + dense * rng.uniform(4.0, 12.0)
                return cls, dims, last[0].trajectory.follower(rng.uniform(0.5, 1.5), gap)
            prof = ego.speed.scaled(k * rng.uniform(0.95, 1.05))
            return cls, dims, Trajectory(Path.build(rng.uniform(5.0, 30.0), y, 0.0, [("straight", 1.0)]), prof,
                                         tau=rng.uniform(-1.5, 1.5))
        added = try_add(make)
        if added is not None:
            last[:] = [added]


_TURN_LENGTH = 12.0  # m of path over which a vehicle turns right at the intersection


def _turn_path(x_lane: float, heading0: float, heading1: float, y_target: float, approach: float) -> Path:
    """Straight approach along the crossing street (heading0) then a smooth right turn onto the main
    street at lane y_target (heading1), then straight."""
    turn = Path.build(0.0, 0.0, heading0, [("turn", _TURN_LENGTH, heading1 - heading0)])
    dy_turn = turn.y[-1]
    y_turn_start = y_target - dy_turn
    y_start = y_turn_start - approach * np.sin(heading0)
    return Path.build(x_lane, y_start, heading0, [("straight", approach),
                                                  ("turn", _TURN_LENGTH, heading1 - heading0), ("straight", 1.0)])


def _plan_cross_traffic(cfg, layout: StreetLayout, rng: np.random.Generator, n: int, try_add) -> None:
    """`crossing`: platoons on the crossing street in both directions, some turning right into the main street.

    A turning vehicle brakes to the speed at which the turn's peak curvature (pi / _TURN_LENGTH) gives a lateral
    acceleration of cfg.turn_lateral_accel, and its followers repeat its motion with a time headway (their delay
    plus their gap at that speed); outside the turn it keeps its cruise speed (no stops)."""
    x_int, lw, k, duration = layout.x_int, layout.lane_width, cfg.object_speed, cfg.duration
    streams = [(x_int + 0.5 * lw, np.pi / 2), (x_int - 0.5 * lw, -np.pi / 2)]
    v_turn = float(np.sqrt(cfg.turn_lateral_accel * _TURN_LENGTH / np.pi))
    last: dict[int, PlannedActor] = {}
    for _ in range(n):
        stream = int(rng.integers(2))
        x_lane, heading = streams[stream]

        def make():
            cls = _moving_class(rng)
            dims = _dims(rng, cls)
            if stream in last and rng.random() < 0.3 + 0.6 * cfg.occlusion:
                prev = last[stream].trajectory
                gap = 0.5 * (last[stream].dims[0] + dims[0]) + (1.0 - 0.7 * cfg.occlusion) * rng.uniform(3.0, 8.0)
                delay = rng.uniform(0.8, 1.6)
                turns = prev.path.heading[-1] != prev.path.heading[0]
                return cls, dims, prev.delayed(delay + gap / v_turn) if turns else prev.follower(delay, gap)
            v_cruise = rng.uniform(6.0, 11.0) * k
            prof = stop_and_go_profile(rng, v_cruise, duration, stop_prob=0.1)
            t_cross = rng.uniform(-0.1, 0.9) * duration  # when it reaches the main street
            approach = 40.0
            if rng.random() < 0.3:  # right turn into the main street
                y_target = layout.lane_y(layout.lanes_per_direction - 1, heading < 0)
                path = _turn_path(x_lane, heading, heading - np.pi / 2, y_target, approach)
                prof = turning_profile(v_cruise, approach, _TURN_LENGTH, v_turn)
            else:
                path = Path.build(x_lane, -np.sign(np.sin(heading)) * (approach + layout.kerb), heading,
                                  [("straight", 1.0)])
            s_at_cross = approach + layout.kerb - layout.half_road
            tau = t_cross - _time_to_travel(prof, s_at_cross)
            return cls, dims, Trajectory(path, prof, 0.0, tau)

        added = try_add(make)
        if added is not None:
            last[stream] = added


def _time_to_travel(prof: SpeedProfile, distance: float) -> float:
    """First time t in [0, 300] s at which prof.distance(t) reaches `distance` (0.01 s grid); 300 if never."""
    t = np.arange(0.0, 300.0, 0.01)
    i = int(np.searchsorted(prof.distance(t), distance))
    return float(t[i]) if i < len(t) else 300.0


def _plan_pedestrians(cfg, layout: StreetLayout, rng: np.random.Generator, ego_end: float,
                      parked: list[PlannedActor], props: list[Prop], try_add) -> None:
    """Standing pedestrians (parked_fraction), kerb-to-kerb crossers (crosswalks in the intersection
    layout, mid-block otherwise) and walkers along the sidewalks.

    `occlusion` (occ): with probability occ a standing pedestrian waits on the sidewalk right behind a
    parked vehicle, and walkers keep to the kerb side of the sidewalk (behind parked vehicles and
    kerbside furniture); with probability 0.9*(1 - occ) a pedestrian is redrawn where a parked
    vehicle or kerbside prop crosses its line of sight from the ego's lane (it would be hidden).
    """
    occ = cfg.occlusion
    n = cfg.n_pedestrians
    n_standing = int(round(cfg.parked_fraction * n))
    duration, k = cfg.duration, cfg.object_speed
    sw_in, sw_out = layout.kerb, layout.sidewalk_outer
    x_max = min(layout.x_hi - 10.0, ego_end + 60.0)
    parked_x = np.array([float(p.trajectory.pose(0.0)[0]) for p in parked])
    parked_side = np.array([float(np.sign(p.trajectory.pose(0.0)[1])) for p in parked])
    parked_half = np.array([0.5 * p.dims[0] for p in parked])
    # occluders of the sidewalks: parked vehicles and props, (x, y, half length)
    occ_x = np.array(parked_x.tolist() + [p.x for p in props])
    occ_y = np.array([float(p.trajectory.pose(0.0)[1]) for p in parked] + [p.y for p in props])
    occ_half = np.array(parked_half.tolist() + [0.5 * p.length for p in props])

    def sidewalk_x() -> float:
        while True:
            x = rng.uniform(0.0, x_max)
            if not layout.in_intersection(x, 1.0):
                return x

    y_ego = -0.5 * layout.lane_width

    def unhidden(x: float, y: float) -> float:
        """x, or an x off the street (rejected) with probability 1 - occ where a parked vehicle or a prop crosses the line of sight from the ego's lane (x from 0 to ego_end) to (x, y)."""
        if not len(occ_x):
            return x
        r = (occ_y - y_ego) / (y - y_ego)  # where the sight line crosses the occluder's y, 0 < r < 1
        lo, hi = r * x, r * x + (1.0 - r) * min(ego_end, 30.0)  # its x there, over the ego's first 30 m
        hidden = (r > 0) & (r < 1) & (lo < occ_x + occ_half + 0.5) & (hi > occ_x - occ_half - 0.5)
        return layout.x_hi + 1e3 if hidden.any() and rng.random() < 0.9 * (1.0 - occ) else x

    def standing():
        dims = _dims(rng, "pedestrian")
        if len(parked) and rng.random() < occ:  # behind a parked vehicle (a car if any), next to the kerb
            cars = [j for j, p in enumerate(parked) if p.cls == "car"] or list(range(len(parked)))
            j = cars[int(rng.integers(len(cars)))]
            x = parked_x[j] + rng.uniform(-0.8, 0.8) * parked_half[j]
            y = parked_side[j] * (sw_in + rng.uniform(0.4, 1.0))
            return "pedestrian", dims, static_trajectory(x, y, rng.uniform(-np.pi, np.pi))
        side = -1.0 if rng.random() < 0.5 else 1.0
        y = side * rng.uniform(sw_in + 0.8, sw_out - 0.6)
        return "pedestrian", dims, static_trajectory(unhidden(sidewalk_x(), y), y, rng.uniform(-np.pi, np.pi))

    crossers: list[PlannedActor] = []

    def crossing():
        dims = _dims(rng, "pedestrian")
        if crossers and rng.random() < 0.6 * cfg.occlusion:  # walk with the last crosser, a step aside
            base = crossers[-1].trajectory
            path = Path.build(base.path.x[0] + rng.choice([-1.0, 1.0]) * rng.uniform(0.7, 1.1), base.path.y[0],
                              base.path.heading[0], [("straight", 1.0)])
            return "pedestrian", dims, Trajectory(path, base.speed, base.s0 - rng.uniform(-0.4, 0.4), base.tau)
        v = rng.uniform(1.2, 1.6) * k
        if layout.x_int is not None:
            x = layout.x_int + (-1 if rng.random() < 0.6 else 1) * (layout.cross_half + 2.0) + rng.uniform(-1, 1)
        else:
            x = rng.uniform(10.0, max(20.0, ego_end + 50.0))
        side = -1.0 if rng.random() < 0.5 else 1.0
        y0, length = side * (layout.kerb + 1.0), 2.0 * (layout.kerb + 1.0)
        x = unhidden(x, y0)
        heading = -side * np.pi / 2
        if v <= 0.0:  # object_speed 0: waits at the kerb
            return "pedestrian", dims, static_trajectory(x, y0, heading)
        t0 = rng.uniform(-0.4 * length / v, 0.8 * duration)
        t1 = t0 + length / v + 0.8
        prof = SpeedProfile.of([(t0, 0.0), (t0 + 0.8, v), (t1 - 0.8, v), (t1, 0.0)])
        return "pedestrian", dims, Trajectory(Path.build(x, y0, heading, [("straight", 1.0)]), prof)

    def walking():
        dims = _dims(rng, "pedestrian")
        side = -1.0 if rng.random() < 0.5 else 1.0
        y = side * (sw_in + 1.2 + (1.0 - occ) * rng.uniform(0.0, sw_out - sw_in - 2.0))
        heading = 0.0 if rng.random() < 0.5 else np.pi
        prof = stop_and_go_profile(rng, rng.uniform(1.1, 1.6) * k, duration, stop_prob=0.15, variation=0.1)
        x = unhidden(sidewalk_x(), y)
        return "pedestrian", dims, Trajectory(Path.build(x, y, heading, [("straight", 1.0)]), prof)

    for i in range(n):
        if i < n_standing:
            try_add(standing, margin=0.3)
            continue
        # the intersection layout sends two of three movers over the crosswalks, the street one of two
        cross = (i - n_standing) % 3 != 2 if layout.x_int is not None else (i - n_standing) % 2 == 0
        added = try_add(crossing if cross else walking, margin=0.3)
        if added is not None and cross:
            crossers.append(added)
