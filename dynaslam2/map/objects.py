"""The object-centric map of the `dynamic` mode (paper III-C): object points stored once in their
object's frame, and each object's pose and velocity along time.

Parameters held (paper III-C): 6 per camera pose, 6 per object pose at each frame that observes it
(`ObjectTrack.observations`), 3 per object point, stored once (`ObjectPoints.X_o`): N' = 6 Nc +
Nc 6 No + No 3 Nop when every object is seen in every frame (`parameter_counts`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dynaslam2.map.columns import ColumnStore


class ObjectPoints(ColumnStore):
    """Object points as contiguous arrays (struct of arrays), indexed by a point id.

    X_o: position in the frame of object `track`; desc: ORB descriptor (the latest inlier observation);
    n_visible / n_found: projected in view / matched as an inlier (culling); alive: not culled;
    weight: summed depth information (1/m^2) of the stereo observations averaged into X_o; coverage: gained at a
    keyframe where its object's tracking was not weak (objects.kf_points_all_objects), not counted as tracked in
    the weak test.
    """

    COLUMNS = (
        ("X_o", (3,), np.float64, 0.0),
        ("desc", (32,), np.uint8, 0),
        ("track", (), np.int64, -1),
        ("n_visible", (), np.int64, 0),
        ("n_found", (), np.int64, 0),
        ("alive", (), bool, False),
        ("weight", (), np.float64, 0.0),
        ("coverage", (), bool, False),
    )

    def __init__(self, capacity: int = 1024) -> None:
        super().__init__(capacity)

    def add(self, track_id: int, X_o: np.ndarray, desc: np.ndarray, weight: np.ndarray | float = 0.0) -> np.ndarray:
        """Append points of object `track_id` (depth information `weight`); returns their ids."""
        ids = self._append(len(X_o))
        self.weight[ids] = weight
        self.X_o[ids] = X_o
        self.desc[ids] = desc
        self.track[ids] = track_id
        self.n_visible[ids] = 1
        self.n_found[ids] = 1
        self.alive[ids] = True
        return ids

    def of_track(self, track_id: int) -> np.ndarray:
        """Ids of the living points of one object."""
        s = self.size
        return np.flatnonzero(self.alive[:s] & (self.track[:s] == track_id))

    def of_tracks(self, track_ids: np.ndarray) -> np.ndarray:
        """Ids of the living points of several objects."""
        s = self.size
        return np.flatnonzero(self.alive[:s] & np.isin(self.track[:s], track_ids))


@dataclass
class ObjectObservation:
    """Object `track` seen at one frame: its pose and velocity there (paper III-A: object frame,
    eq. 5) and which keypoints observed which object points.

    kp_idx / pt_ids: inlier keypoints of the frame and their object points; kf_id: the keyframe made
    from that frame (-1 if none), which makes the observation a member of BA windows; T_c_w: the pose of
    the camera that made it (motion-compensated box association).
    """

    frame_index: int
    timestamp: float
    T_w_o: np.ndarray
    v_o: np.ndarray
    w_o: np.ndarray
    instance_id: int
    kp_idx: np.ndarray
    pt_ids: np.ndarray
    box2d: tuple[float, float, float, float] | None = None
    kf_id: int = -1
    T_c_w: np.ndarray | None = None  # (4, 4) world-to-camera pose of the frame
    measured: bool = True  # False: T_w_o is the constant-velocity prediction (instance association only)

    @property
    def n_points(self) -> int:
        return int(len(self.pt_ids))


@dataclass
class ObjectTrack:
    """One tracked object: id, class and its observations in time order (one per frame seen).

    `velocity_known`: v_o/w_o of the last observation come from two close observations, so the
    constant-velocity prediction (eq. 5) applies. `state_mean` (6,) / `state_cov` (6, 6): constant-
    velocity filter of the object-frame origin (world position, world velocity) at the last observation;
    `rot_cov` (6, 6): covariance of the rotation filter (rotation, angular velocity), whose mean is the last
    observation's rotation and w_o. `mask_centre_o`: the body point (object frame) its instance mask's centre
    measures (`ObjectTracker._mask_centre_register`). `appearance`: colour histograms of its instance at its
    latest observations (`tracking.appearance`, newest last, at most objects.appearance_gallery).
    """

    track_id: int
    cls: str
    observations: list[ObjectObservation] = field(default_factory=list)
    velocity_known: bool = False
    state_mean: np.ndarray | None = None
    state_cov: np.ndarray | None = None
    rot_cov: np.ndarray | None = None
    mask_centre_o: np.ndarray | None = None
    appearance: list[np.ndarray] = field(default_factory=list)

    @property
    def last(self) -> ObjectObservation:
        return self.observations[-1]

    def at_frame(self, frame_index: int) -> ObjectObservation | None:
        """The observation at `frame_index` (searched from the newest), or None."""
        for obs in reversed(self.observations):
            if obs.frame_index == frame_index:
                return obs
            if obs.frame_index < frame_index:
                return None
        return None


class ObjectMap:
    """All objects of a run: tracks by id and their points (object-centric, III-C)."""

    def __init__(self) -> None:
        self.tracks: dict[int, ObjectTrack] = {}
        self.points = ObjectPoints()
        self.next_track_id = 0

    def new_track(self, cls: str) -> ObjectTrack:
        track = ObjectTrack(self.next_track_id, cls)
        self.tracks[track.track_id] = track
        self.next_track_id += 1
        return track

    def remove_track(self, track_id: int) -> None:
        """Forget track `track_id` and its points."""
        del self.tracks[track_id]
        self.points.alive[self.points.of_track(track_id)] = False

    def add_points(self, track_id: int, X_o: np.ndarray, desc: np.ndarray,
                   weight: np.ndarray | float = 0.0) -> np.ndarray:
        return self.points.add(track_id, X_o, desc, weight)

    def parameter_counts(self, n_cameras: int) -> dict[str, int]:
        """Parameters of the stored representation (paper III-C): 6 per camera pose, 6 per stored
        object pose (one per observing frame), 3 per living object point (each stored once);
        `total` = N'. `per_frame_points` is what independent per-frame point clouds would need
        (the paper's N = 6 Nc + Nc No 3 Nop with the same observations)."""
        n_obs = sum(len(t.observations) for t in self.tracks.values())
        n_pts = int(np.count_nonzero(self.points.alive[: self.points.size]))
        per_frame = sum(3 * len(o.pt_ids) for t in self.tracks.values() for o in t.observations)
        out = {"cameras": 6 * n_cameras, "object_poses": 6 * n_obs, "object_points": 3 * n_pts}
        out["total"] = out["cameras"] + out["object_poses"] + out["object_points"]
        out["per_frame_points"] = 6 * n_cameras + per_frame
        return out
