"""The SLAM configuration tree: every threshold of the system lives here.

Load with `load_config(yaml_path, ["section.key=value", ...])`. Defaults follow ORB-SLAM2 (ref. [1]
of the paper) and DynaSLAM II where the paper states them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from dynaslam2.classes import DYNAMIC_CLASSES
from dynaslam2.config_tree import build, load_yaml, parse_overrides
from dynaslam2.errors import ConfigError

Mode = Literal["dynamic", "masked", "static"]


@dataclass
class ORBConfig:
    """ORB extraction on an image pyramid, distributed over a grid (ORB-SLAM2's ORBextractor)."""

    n_features: int = 2000
    n_levels: int = 8
    scale_factor: float = 1.2
    ini_th_fast: int = 20
    min_th_fast: int = 7
    edge_threshold: int = 19
    patch_size: int = 31
    cell_size: int = 30
    threads: int = 2  # extract_pair: the right image in a worker when > 1
    # The worker of extract_pair: "process" (a Python process per extractor, started at its first pair and fed
    # through pipes: no shared GIL, both images in parallel) or "thread" (shares the GIL with the left image).
    worker: Literal["process", "thread"] = "process"

    def validate(self) -> None:
        if self.n_features <= 0:
            raise ConfigError(f"orb.n_features: expected a positive integer, got {self.n_features}")
        if self.n_levels < 1:
            raise ConfigError(f"orb.n_levels: expected >= 1, got {self.n_levels}")
        if not self.scale_factor > 1.0:
            raise ConfigError(f"orb.scale_factor: expected > 1, got {self.scale_factor}")
        if not 0 < self.min_th_fast <= self.ini_th_fast:
            raise ConfigError(f"orb: expected 0 < min_th_fast <= ini_th_fast, got {self.min_th_fast}, {self.ini_th_fast}")
        if self.edge_threshold < 19 or self.patch_size != 31:
            raise ConfigError(f"orb: the rBRIEF pattern needs patch_size 31 and edge_threshold >= 19, "
                              f"got {self.patch_size}, {self.edge_threshold}")
        if self.cell_size < 8 or self.threads < 1:
            raise ConfigError(f"orb: expected cell_size >= 8 and threads >= 1, got {self.cell_size}, {self.threads}")


@dataclass
class StereoConfig:
    """Stereo matching (ORB-SLAM2's Frame::ComputeStereoMatches)."""

    th_high: int = 100
    th_low: int = 50  # a left-right match needs descriptor distance < (th_high + th_low) / 2
    row_band_scale: float = 2.0  # right keypoints are candidates within +-row_band_scale * scale(level) rows
    sad_window: int = 5  # SAD patch half-width: 11 columns
    # SAD patch half-height: 11x5. ORB-SLAM2's 11x11 (5) assumes a fronto-parallel patch; on the ground the
    # disparity grows ~baseline/camera-height px per row, which biases corners by up to ~1.5 px.
    sad_half_height: int = 2
    sad_search: int = 5  # SAD search +-5 px around the descriptor match, at the keypoint's level
    sad_centre: Literal["mean", "pixel"] = "mean"  # subtract each patch's mean (or centre pixel, ORB-SLAM2)
    # Sub-pixel minimum of the SAD curve: "equiangular" (V fit, the shape of a SAD minimum) or "parabola"
    # (ORB-SLAM2; biased towards whole-pixel disparities, see features.stereo).
    subpixel: Literal["equiangular", "parabola"] = "equiangular"
    max_subpixel_delta: float = 1.0  # sub-pixel vertex further than this from the best SAD offset: rejected
    outlier_sad_factor: float = 1.5 * 1.4  # reject matches with SAD > factor * median SAD
    th_depth_baselines: float = 40.0
    right_features_factor: float = 1.0  # right-image ORB budget = factor x orb.n_features (more: more depths)
    # `dynamic` mode: keypoints on dynamic instances that got no depth (no right keypoint matched them:
    # about half of them on small, far objects at 640x480) are searched along their row of the right
    # image (SAD, depths row_search_min_depth_m to objects.max_point_depth_m); kept when the best SAD is
    # below row_search_uniqueness x the best one more than 1 px away. Static keypoints are untouched.
    dynamic_row_search: bool = True
    row_search_min_depth_m: float = 2.0
    row_search_uniqueness: float = 0.5
    # True: the row search scores a keypoint's window on the pixels of its own instance only (segmentation-
    # aware SAD: a pedestrian is ~10 px wide at 15 m, narrower than the 11 px window, and the background
    # behind it lies at another disparity), with >= row_search_min_support of the window on it. On the
    # pedestrian keypoints left without depth by match_stereo (sim crossing s0, 30 frames, 1060 keypoints with
    # objects.densify_features=500, rendered depth as reference): depths found 331 -> 396, within 1 px 94 % ->
    # 98 % (support 0.3: 312). A pedestrian of 12 x 44 px at 16 m (crossing s7) had a depth on 0-5 of its 6-17
    # keypoints per frame with the whole window, 2-13 with its own pixels. bench_dynamic's four scenarios (world 2,
    # 150 fr, 640x480), False -> True: seeds 0-4 id switches while unoccluded 1 -> 0, all 29 -> 23, TP 0.804 ->
    # 0.821, object ATE 0.212 -> 0.228 m, short gaps kept 29/31 -> 29/33 (more pedestrian tracks, more gaps), ego
    # ATE 0.0212 -> 0.0222 m; seeds 5-9 1 -> 0, 11 -> 12, 0.830 -> 0.838, 0.193 -> 0.198 m, 21/21 -> 21/21,
    # 0.0269 -> 0.0279 m; following seeds 10-19 0 -> 0, 1 -> 2, TP 0.790 -> 0.810, 0.156 -> 0.173 m, ego 0.0274 ->
    # 0.0262 m. (Measured before world 2 on traffic and following s0/s1 alone, it had raised the object ATE 0.249
    # -> 0.296 m for TP 0.79 -> 0.80; the depths it adds are mostly of outline corners, see objects.densify_features.)
    row_search_instance_mask: bool = True
    row_search_min_support: float = 0.15

    def validate(self) -> None:
        if not 0 < self.th_low <= self.th_high <= 256:
            raise ConfigError(f"stereo: expected 0 < th_low <= th_high <= 256, got {self.th_low}, {self.th_high}")
        if self.sad_window < 1 or self.sad_search < 1 or self.sad_half_height < 0:
            raise ConfigError(f"stereo: expected sad_window >= 1, sad_search >= 1, sad_half_height >= 0, got "
                              f"{self.sad_window}, {self.sad_search}, {self.sad_half_height}")
        if not (self.row_search_min_depth_m > 0 and 0 < self.row_search_uniqueness <= 1):
            raise ConfigError(f"stereo: expected row_search_min_depth_m > 0 and row_search_uniqueness in (0, 1], got "
                              f"{self.row_search_min_depth_m}, {self.row_search_uniqueness}")
        if not 0.0 <= self.row_search_min_support <= 1.0:
            raise ConfigError(f"stereo.row_search_min_support: expected in [0, 1], got {self.row_search_min_support}")
        if not (self.row_band_scale > 0 and self.outlier_sad_factor > 0 and self.right_features_factor > 0):
            raise ConfigError("stereo: row_band_scale, outlier_sad_factor and right_features_factor must be positive")


@dataclass
class MatcherConfig:
    """Descriptor matching thresholds (ORB-SLAM2's ORBmatcher)."""

    th_high: int = 100
    th_low: int = 50
    nn_ratio: float = 0.9


@dataclass
class TrackingConfig:
    """Camera tracking, keyframe decision, loss and relocalization (ORB-SLAM2's Tracking)."""

    # Map initialization from the first stereo/RGB-D frame.
    init_min_points: int = 500
    # RGB-D: depth from the depth image even when a right image exists.
    use_depth_image: bool = False
    # masked/dynamic modes: dilation of dynamic-class instance masks, in pixels.
    mask_dilation_px: int = 5
    # Motion-model search radius (px at level 0, scaled by the keypoint level) and minimum matches.
    motion_radius: float = 7.0
    motion_nn_ratio: float = 1.0
    motion_min_matches: int = 20
    # Reference-keyframe fallback: minimum descriptor matches and ratio test.
    ref_min_matches: int = 15
    ref_nn_ratio: float = 0.7
    # Pose-only tracking succeeds with this many inlier map matches (motion model / reference KF).
    min_pose_inliers: int = 10
    # Local map: keyframes (covisible with the frame's points) and projection search radius factor.
    local_max_keyframes: int = 80
    local_neighbours: int = 10
    local_radius: float = 1.0
    local_radius_relocalized: float = 5.0
    local_nn_ratio: float = 0.8
    view_cos_limit: float = 0.5
    # Tracking is good with at least this many inliers after local-map tracking (50 after relocalization).
    min_inliers: int = 30
    min_inliers_relocalized: int = 50
    # ... and at least this fraction of the last frame's inliers (a sudden collapse = a jump).
    min_inlier_ratio_to_last: float = 0.2
    # Keyframe insertion (ORB-SLAM2's NeedNewKeyFrame; max_frames defaults to the frame rate).
    min_frames: int = 0
    max_frames: int = 10
    close_tracked_max: int = 100
    close_untracked_min: int = 70
    ref_ratio: float = 0.75
    ref_ratio_stereo_force: float = 0.25
    keyframe_min_inliers: int = 15
    new_points_min: int = 100
    # Relocalization: candidate keyframes, matches, PnP RANSAC, final inliers.
    reloc_candidates: int = 10
    reloc_min_matches: int = 15
    reloc_nn_ratio: float = 0.75
    reloc_ransac_iterations: int = 300
    reloc_ransac_px: float = 4.0
    reloc_min_pnp_inliers: int = 10
    # Frames of failed relocalization before a new map segment starts from the motion prior.
    lost_frames_before_new_segment: int = 5

    def validate(self) -> None:
        for name in ("init_min_points", "motion_min_matches", "min_inliers", "max_frames", "reloc_candidates"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"tracking.{name}: expected a positive integer, got {getattr(self, name)}")
        if self.mask_dilation_px < 0:
            raise ConfigError(f"tracking.mask_dilation_px: expected >= 0, got {self.mask_dilation_px}")
        if self.min_frames > self.max_frames:
            raise ConfigError(f"tracking.min_frames ({self.min_frames}) must not exceed tracking.max_frames "
                              f"({self.max_frames})")


@dataclass
class MappingConfig:
    """Local mapping: new points, fusion, culling, local BA window (ORB-SLAM2's LocalMapping)."""

    covisibility_min_weight: int = 15
    triangulation_neighbours: int = 10
    triangulation_max_desc_dist: int = 50
    triangulation_nn_ratio: float = 0.6
    triangulation_min_parallax_cos: float = 0.9998
    fuse_neighbours: int = 10
    fuse_second_neighbours: int = 5
    fuse_radius: float = 3.0
    # Map-point culling: found/visible ratio; after a few keyframes, culled when its observation count
    # (a stereo observation counts 2, as ORB-SLAM2) is at most cull_obs_threshold.
    cull_found_ratio: float = 0.25
    cull_obs_threshold: int = 3
    cull_after_keyframes: int = 2
    # Keyframe culling: redundant if this fraction of its close points is seen by >= N other keyframes.
    kf_cull_redundancy: float = 0.9
    kf_cull_observers: int = 3
    # Local BA: window of covisible keyframes around the new one, and at most this many fixed
    # keyframes (those outside the window that see the most window points). Measured with the default
    # optim.local_ba_* (static mode, 100 frames): 10 + 5 fixed cost 0.77x the BA CPU time on sim static s1
    # but raised the ATE 0.043 -> 0.050 m (s1), 0.056 -> 0.061 m (s0); KITTI 06 0.0707 -> 0.0701 m.
    ba_max_keyframes: int = 20
    ba_max_fixed_keyframes: int = 10
    # Points in the BA problem need this many observing keyframes (1 = all, as ORB-SLAM2).
    ba_min_views: int = 2

    def validate(self) -> None:
        if self.covisibility_min_weight < 1:
            raise ConfigError(f"mapping.covisibility_min_weight: expected >= 1, got {self.covisibility_min_weight}")
        if not 0.0 <= self.cull_found_ratio <= 1.0:
            raise ConfigError(f"mapping.cull_found_ratio: expected in [0, 1], got {self.cull_found_ratio}")
        if self.ba_max_keyframes < 1:
            raise ConfigError(f"mapping.ba_max_keyframes: expected >= 1, got {self.ba_max_keyframes}")


@dataclass
class ObjectOptimConfig:
    """Bundle adjustment with objects (paper III-D, eq. 2-6); the reprojection terms use OptimConfig's
    chi2 thresholds, iterations and LM settings.

    Sigmas of eq. (3) and (4) grow linearly with the time between consecutive observations of an
    object: sigma = base * dt. Huber deltas are the square roots of the chi2 values (95%: 6 dof for
    eq. 3, 3 dof for eq. 4).
    """

    # eq. (2): "camera_in_object" = the camera pose in the object frame Q = T_o_c as the variable
    # (gtsam's built-in projection factors on (Q, X_o)); "direct" = one Python factor on (T_w_c, T_w_o, X_o)
    # per object observation (the reference formulation, same optimum, slower).
    parametrization: Literal["camera_in_object", "direct"] = "camera_in_object"
    sigma_linear_acc: float = 2.0  # eq. (3): sigma of v_{i+1} - v_i per second of dt (m/s^2)
    sigma_angular_acc: float = 0.5  # eq. (3): sigma of w_{i+1} - w_i per second of dt (rad/s^2)
    sigma_motion_xyz: float = 0.2  # eq. (4): sigma of each point's position residual per second of dt (m/s)
    chi2_velocity: float = 12.592  # Huber delta^2 of eq. (3) (6 dof)
    chi2_motion: float = 7.815  # Huber delta^2 of eq. (4), per object point (3 dof)
    # eq. (4) with the object points as variables (exact joint optimum; one dense factor over all the
    # object's points per frame pair) or held at their estimate at the start of each LM stage (eq. 2
    # refines them; measured faster, see benchmarks/bench_object_ba.py).
    motion_points_variable: bool = False
    # eq. (4) with constant points: "moments" = one factor per object, 12 rows per frame pair, with exactly the
    # normal equations and Huber cost of "stacked" (a factor per frame pair, 3 rows per point: the reference
    # form); see object_factors.motion_factor_object
    motion_form: Literal["moments", "stacked"] = "moments"
    # LM's initial lambda of the BA with objects (optim.lambda_initial: pose-only). Measured on 42 windows of
    # traffic s0 640x480 against the converged optimum: 1e-4 ends ~50x closer (cameras) in ~1.1x the CPU time
    # (5 + 10); 1e-4 with 1 + 0 iterations 0.34x the CPU and ~16x closer there, but on synthetic windows
    # (tests/test_object_ba.py) 1 + 0 ends farther than 5 + 10 from lambda 1: kept at ORB-SLAM2's settings
    lambda_initial: float = 1.0
    # An object observation with fewer used point observations has no reprojection term (eq. 2): its pose follows its
    # neighbours in time through eq. (3)-(5) (object_ba._object_structure).
    min_observation_points: int = 5
    # Hold (a strong prior, as the gauge) each observation whose pose the tracker measured (not a box join's
    # prediction) and that has min_observation_points reprojection terms or more of which fewer are of points seen at
    # another observation of the window (object_ba._held_observations): its points were made at non-keyframes or at
    # its keyframe, so eq. (2) cannot place it (each single-view point follows the pose), and eq. (3)-(4) alone would
    # set it to the window's extrapolated motion and carry its points along. Crossing s99's car turning out of an
    # occlusion (f33, 41 of its 42 points new to the window): rotation error 6.2 deg from the tracker, 18.1 after the
    # BA (17.6 without eq. 3, 8.6 without eq. 4); the next pose-only poses followed the straightened points (16-36 deg
    # off) until a new track took the car (the one id switch on an unoccluded track); held, 6.2 and the track kept.
    # Per track it can go either way where the measured poses lag too (crossing s88 gt2, a 90 deg turn, 0.70 ->
    # 1.90 m); holding predictions as well broke s41 gt2 (0.72 -> 3.89 m). Not in the paper. Off -> on (world 3, 150
    # fr, 640x480; at 177a404), object ATE / TP / id switches (unoccluded) / short gaps kept / ego ATE: traffic,
    # crossing, following, static seeds 0-4 0.232 -> 0.227 m / 84.0 -> 84.0 % / 5 (0) -> 5 (0) / 38 of 38 / 0.0233
    # -> 0.0232 m, 5-9 0.176 -> 0.175 / 84.6 -> 84.7 / 0 -> 0 / 26 of 26 / 0.0275 -> 0.0276; traffic, crossing,
    # static 10-14 0.199 -> 0.194 / 83.8 -> 84.0 / 2 -> 2 / 55 of 55 / 0.0266 -> 0.0257, 15-19 0.201 -> 0.210 / 83.4
    # -> 83.5 / 1 -> 1 / 42 of 42 / 0.0217 -> 0.0214, 20-24 0.184 -> 0.183 / 81.8 -> 81.8 / 1 -> 1 / 27 of 29 /
    # 0.0250 -> 0.0250, 25-29 0.210 -> 0.209 / 84.4 -> 84.4 / 1 -> 1 / 31 -> 32 of 32 / 0.0217 -> 0.0218; crossing
    # 40-54 0.264 -> 0.264 / 74.6 -> 74.6 / 18 -> 16 / 86 of 87 / 0.0167 -> 0.0160, 55-69 0.277 -> 0.264 / 74.0 ->
    # 74.0 / 12 -> 12 / 85 of 85 / 0.0184 -> 0.0171, 70-84 0.285 -> 0.287 / 74.2 -> 74.2 / 6 -> 8 / 106 of 108 ->
    # 104 of 107 / 0.0160 -> 0.0150, 85-99 0.297 -> 0.301 / 75.8 -> 75.9 / 10 (1) -> 9 (0) / 125 of 128 -> 123 of
    # 126 / 0.0177 -> 0.0180; following 10-19 0.169 -> 0.169 / 83.1 -> 83.1, 20-39 0.187 -> 0.186 / 82.1 -> 82.2,
    # 0-39 ego 0.0286 -> 0.0285 (masked 0.0297). No id switch on an unoccluded track on any group, object ATE lower
    # on 8 of 12 groups (higher on 15-19, 70-84, 85-99), nine short gaps lost on the fresh groups either way,
    # crossing 85-99 just over 0.3 m.
    hold_single_view_observations: bool = True
    # eq. (2)'s stereo residuals as [u, v, disparity], the disparity at sigma / disparity_weight (the object
    # pose-only optimization's model, objects.pose_disparity_weight); 0: ORB-SLAM2's isotropic [u, v, u_right]
    # (a disparity sigma of ~1.4 px at level 0 where the sub-pixel SAD gives ~0.1 px), with which the BA's
    # object points were worse than the tracker's depth-weighted fused ones: against the rendered depth
    # (diagnostic on crossing s0, 71 BA windows x objects) the BA raised the points' shape error in 69 % of
    # them, 3: in 49 %. End to end on bench_dynamic's 12 sequences (150 fr, 640x480), 0 -> 3 -> 10: object ATE
    # 0.301 -> 0.280 -> 0.313 m, mean ego ATE 0.0222 -> 0.0228 -> 0.0251 m, id switches 34 -> 31 -> 35. On its 20
    # sequences (seeds 0-4) after keep_object_origins, 0 -> 3: 0.306 -> 0.286 m, 0.0212 -> 0.0222 m, 63 -> 60 (the
    # noise of these means: a 0.5 % change of sigma_motion_xyz moves them by ~0.01 m, ~0.0001 m (single sequences
    # up to 6 mm) and ~2).
    disparity_weight: float = 3.0
    # Joint case (camera and object weak): True = the static terms (eq. 1) linearized once at the window's
    # estimate (Huber weights there; after the static local BA with objects.static_ba_first) and reduced to
    # the free cameras by eliminating the static points (optim/static_schur.py), the points following the
    # cameras by back-substitution; False = every static point a variable, eq. (1) relinearized at every LM iteration (the
    # exact joint problem). Measured on the captured windows of traffic s0/s1 and following s0 640x480: 0.23-0.24x
    # the CPU time of the joint windows (median ~65 ms against ~285), lower final cost on 62 of 64
    # (object_ba.py's docstring). End to end (dynamic mode, bench_dynamic's traffic, following, crossing and
    # static s0-s2, 150 fr, 640x480, objects.static_ba_first on), False -> True: mean ego ATE 0.0283 -> 0.0273 m (lower
    # on 7 of 12), object ATE 0.298 -> 0.297 m, TP 0.732 -> 0.731, id switches 60 -> 61; traffic s0's 31 joint
    # keyframes: median BA with objects 896 -> 215 ms CPU (2 loaded cores). (Measured worse at earlier states of
    # the object tracking, when object ATE was ~0.5 m: ego 0.026 -> 0.034 m on traffic and following s0-s2.)
    static_reduced: bool = True
    # LM damping (whitened units) of each static point's block in that reduction (the points take one step):
    # without it, far points (depth information ~1e-6) jump by hundreds of metres for a millimetre of camera
    # motion. Summed final cost on the 50 windows of traffic s0: 1e-6 / 1e-4 / 1e-2 / 1 -> 146694 / 146660 /
    # 146691 / 146757 (the exact form 146723). With 1 (points barely move, as in the exact form's first LM
    # steps) end to end (traffic and following s0-s2): mean ego ATE 0.0240 m (exact form 0.0255, per sequence
    # -0.009 .. +0.003), object ATE 0.500 m (0.484; traffic s1 0.55 -> 0.65, s2 0.50 -> 0.44), but the final
    # cost is higher than the exact form's on 32 of 35 joint windows of traffic s0 (median +0.8 on ~4500) and the
    # cameras end 1.2 mm from the exact optimum on a synthetic window (tests: 1 mm with 1e-4).
    static_point_damping: float = 1e-4
    # eq. (2) (object reprojection) of each object linearized at each LM stage's start (Huber weights there) and
    # reduced to its observations' poses by eliminating its points (optim/object_ba.py `_object_reduction`,
    # static_schur.py, each point block damped by lambda_initial as in the exact form's first LM step), the points
    # following by back-substitution after the stage; False: every object point a gtsam variable (the exact
    # form). "camera_in_object" only. Replay of traffic s0's windows with every object in the BA
    # (objects.ba_all_objects): 0.79x the CPU time; the default's windows (~100 object points): no gain. End to end
    # with objects.kf_points_all_objects and ba_all_objects (crossing 70-84 / 55-69, 150 fr 640x480), object ATE
    # 0.285 / 0.251 m against the exact form's 0.309 / 0.235, TP 75.2 / 74.9 % against 75.4 / 75.1, ego 0.0147 /
    # 0.0146 against 0.0151 / 0.0154 m; one id switch on an unoccluded track (s77 gt22) against none. (With the
    # points damped by 1e-4 instead, the BA moved them far more: 0.380 / 0.400 m.) bench_dynamic.py with the three
    # options, run alone (854ce31): BA per keyframe on traffic s0 / s1 142 / 93 ms against static's 60 / 54 (2.37x /
    # 1.72x; without this option 2.81x / 1.98x at 1e7b07a), fps 0.42x static.
    object_points_reduced: bool = False
    tail_seconds: float = 2.0  # object-weak BA (III-D): keyframes within this time of the newest are free

    def validate(self) -> None:
        if not (self.sigma_linear_acc > 0 and self.sigma_angular_acc > 0 and self.sigma_motion_xyz > 0):
            raise ConfigError("optim.objects.sigma_linear_acc/sigma_angular_acc/sigma_motion_xyz: expected > 0")
        if not (self.chi2_velocity > 0 and self.chi2_motion > 0):
            raise ConfigError("optim.objects.chi2_velocity/chi2_motion: expected > 0")
        if self.min_observation_points < 3:
            raise ConfigError(f"optim.objects.min_observation_points: expected >= 3, got {self.min_observation_points}")
        if not self.tail_seconds > 0:
            raise ConfigError(f"optim.objects.tail_seconds: expected > 0, got {self.tail_seconds}")
        if not self.disparity_weight >= 0:
            raise ConfigError(f"optim.objects.disparity_weight: expected >= 0, got {self.disparity_weight}")
        if not self.lambda_initial > 0:
            raise ConfigError(f"optim.objects.lambda_initial: expected > 0, got {self.lambda_initial}")
        if self.object_points_reduced and self.parametrization != "camera_in_object":
            raise ConfigError("optim.objects.object_points_reduced: needs parametrization=camera_in_object, got "
                              f"{self.parametrization}")
        if not self.static_point_damping > 0:
            raise ConfigError(f"optim.objects.static_point_damping: expected > 0, got {self.static_point_damping}")


@dataclass
class OptimConfig:
    """gtsam optimizations: pose-only (ORB-SLAM2's PoseOptimization) and local BA (LocalBundleAdjustment).

    Chi-square thresholds are the 95% quantiles for 2 (mono) and 3 (stereo) dof; the Huber kernels use
    their square roots as delta, as ORB-SLAM2.
    """

    chi2_mono: float = 5.991
    chi2_stereo: float = 7.815
    pose_rounds: int = 4  # optimize / classify outliers rounds
    pose_iterations: int = 10  # LM iterations per round
    pose_robust_rounds: int = 3  # rounds with the Huber kernel; the later ones run without it
    pose_min_points: int = 3  # fewer correspondences: the pose is returned unchanged, no inlier
    pose_min_inliers: int = 10  # stop the rounds when fewer inliers remain
    pose_restart_rounds: bool = False  # True: every round restarts from the initial pose (ORB-SLAM2); False: warm
    # BA with objects (optim/object_ba.py): LM iterations with Huber, outlier removal, then without the
    # outliers and without kernel (ORB-SLAM2's 5 + 10)
    ba_iterations_robust: int = 5
    ba_iterations_refine: int = 10
    # Static local BA (optim/local_ba.py), the same stages. Measured (static mode, same process per row;
    # ATE m / median BA CPU ms per keyframe) for 5 + 10 from lambda 1, then from 1e-4: 1 + 0, 2 + 0, 1 + 1:
    #   sim static s0 150 fr: 0.218 / 552, 0.068 / 162, 0.057 / 290, 0.053 / 340
    #   sim static s1 150 fr: 0.126 / 460, 0.043 / 151, 0.046 / 249, 0.047 / 329
    #   KITTI 06 51 fr: 0.0721 / 169, 0.0707 / 61, (2 + 0: 0.0684), 0.0690 / 126
    # 1 + 0 is the fastest and 2-3x more accurate than the old 5 + 10; more iterations gain < 20%, not always.
    local_ba_iterations_robust: int = 1
    local_ba_iterations_refine: int = 0
    min_depth: float = 1e-3  # observations of points closer than this (or behind) are outliers
    # LM stops early when an iteration decreases the cost by less than this fraction
    pose_relative_error_tol: float = 1e-5
    ba_relative_error_tol: float = 1e-2  # 1e-3: ~2x the LM iterations for < 1% lower cost on bench_ba.py
    # LM damping H + lambda * I on whitened (pixel / sigma) residuals; diagonal_damping: lambda * diag(H).
    # Measured on bench_ba.py: lambda * I from 1.0 needs fewer rejected steps than Marquardt's diag(H) from 1e-3.
    lambda_initial: float = 1.0
    # Static local BA's initial lambda. Its windows start near the optimum (only the new keyframe and points
    # are off), where lambda = 1 damps the depth of far points (small diag(H)) and LM stops on the 1% rule
    # far from the optimum: on captured SLAM windows (KITTI 06, sim static s0) 1e-4 ends ~20x closer to
    # the converged windows in 0.8x the CPU time (5 + 10 iterations), sim static s0 ATE 0.169 -> 0.048 m.
    local_ba_lambda_initial: float = 1e-4
    # Static local BA's solver: "schur" = LM in numpy on the reduced camera system (optim/schur_lm.py, the
    # points eliminated in closed form), "gtsam" = gtsam's LM on built-in stereo factors (the reference; the
    # pose-only and the BA with objects always use gtsam). Same steps and optimum; see schur_lm.py for speed.
    local_ba_solver: Literal["schur", "gtsam"] = "schur"
    diagonal_damping: bool = False
    # True: lambda scaled by a fixed factor 10 after each step (gtsam's default); False: Nielsen's update
    # from the step's model fidelity. Measured on bench_ba.py: False rejects fewer steps, the same cost
    # in 0.7-0.8x the CPU time per iteration (local BA and pose-only N=300).
    lambda_fixed_factor: bool = False
    # Measured on bench_ba.py (same run): SEQUENTIAL_CHOLESKY 0.85-0.89x the CPU time of MULTIFRONTAL_CHOLESKY,
    # identical result (points-first order: the points' cliques are single variables anyway).
    linear_solver: Literal["MULTIFRONTAL_CHOLESKY", "MULTIFRONTAL_QR", "SEQUENTIAL_CHOLESKY"] = "SEQUENTIAL_CHOLESKY"
    # BA elimination order: SCHUR = all points, then the keyframes (the Schur complement, known from the
    # problem's structure at no cost); COLAMD / METIS = gtsam's fill-reducing orderings computed on the graph.
    ordering: Literal["SCHUR", "COLAMD", "METIS"] = "SCHUR"
    objects: ObjectOptimConfig = field(default_factory=ObjectOptimConfig)  # BA with objects (eq. 2-6)

    def validate(self) -> None:
        if not (self.chi2_mono > 0 and self.chi2_stereo > 0):
            raise ConfigError(f"optim.chi2_mono/chi2_stereo: expected positive, got {self.chi2_mono}, {self.chi2_stereo}")
        if self.pose_rounds < 1 or self.pose_iterations < 1:
            raise ConfigError(f"optim.pose_rounds/pose_iterations: expected >= 1, got {self.pose_rounds}, "
                              f"{self.pose_iterations}")
        if self.pose_min_points < 3:
            raise ConfigError(f"optim.pose_min_points: expected >= 3, got {self.pose_min_points}")
        if min(self.ba_iterations_robust, self.ba_iterations_refine, self.local_ba_iterations_robust,
               self.local_ba_iterations_refine) < 0:
            raise ConfigError("optim.ba_iterations_robust/ba_iterations_refine/local_ba_iterations_robust/"
                              "local_ba_iterations_refine: expected >= 0")
        if self.local_ba_solver == "schur" and self.diagonal_damping:
            raise ConfigError("optim.diagonal_damping=true: the static local BA's 'schur' solver damps with lambda * I; "
                              "set optim.local_ba_solver=gtsam for Marquardt's diag(H) damping")
        if not (self.pose_relative_error_tol >= 0 and self.ba_relative_error_tol >= 0):
            raise ConfigError("optim.pose_relative_error_tol/ba_relative_error_tol: expected >= 0")
        if not (self.lambda_initial > 0 and self.local_ba_lambda_initial > 0):
            raise ConfigError(f"optim.lambda_initial/local_ba_lambda_initial: expected > 0, got {self.lambda_initial}, "
                              f"{self.local_ba_lambda_initial}")


@dataclass
class VehicleLengthsConfig:
    """A length in metres per vehicle class (0: none)."""

    car: float = 4.0
    van: float = 4.8
    truck: float = 6.0

    def __post_init__(self) -> None:
        for name in ("car", "van", "truck"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"objects.border_cut_length_m.{name}: expected >= 0, got {getattr(self, name)}")


@dataclass
class ObjectsConfig:
    """Object tracking of the `dynamic` mode (paper III-B to III-D): creation, association, pose,
    keyframes for weak object tracking."""

    # Creation: an unclaimed dynamic-class instance with this many keypoints with stereo depth
    # closer than max_point_depth_m ("new nearby keypoints") creates an object.
    min_new_points: int = 10
    # Not in the paper: an instance of these classes short of min_new_points close keypoints also counts its keypoints
    # without stereo depth, placed at its mask's depth (`MaskMeasurement.depth`, found within mask_depth_max_m) and
    # weighted by the mask disparity's sigma, unless a track of its class seen within join_max_gap_s could be there; and a
    # pose claim by a track of those classes spares the track begun on its object while it was lost (`_successor`, as a
    # vote does). `crossing` 40-54 / 55-69 / 70-84 / 85-99 / 100-114 / 115-129 (world 3, 150 fr, 640x480), () ->
    # (pedestrian,): TP 74.9 / 73.9 / 74.4 / 76.0 / 78.6 / 76.0 -> 77.1 / 76.5 / 76.7 / 77.5 / 80.5 / 77.8 %, object ATE
    # 0.238 / 0.273 / 0.282 / 0.274 / 0.285 / 0.252 -> 0.251 / 0.293 / 0.296 / 0.290 / 0.304 / 0.283 m, id switches 55 ->
    # 78, none on an unoccluded track (without the claim rule one: s42 gt28, the old track took the person back). Points
    # weighted 0 instead let one wrong stereo depth (16.9 m for 31.3 m) move every other point of the person 5 m through
    # fuse_shape_only's common shift (s91 gt20, 0.24 -> 1.83 m). mask_depth_max_m: a person begun at 38 m (6 m per pixel
    # of disparity) carried its depth error into range (s97 gt26, 0.27 -> 1.14 m); not measured alone. The default, with
    # pedestrian_report_coast_s (below): together they track 80.7 % of `crossing`'s 90 seeds (README).
    mask_depth_classes: tuple[str, ...] = ("pedestrian",)
    mask_depth_max_m: float = 30.0
    # A small (far) instance with fewer also creates one when its close keypoints are >= min_inliers
    # and >= small_new_fraction of its free keypoints (0 disables). Off: bench_dynamic's 20 sequences
    # (traffic, following, crossing, static s0-s4, 150 fr, 640x480), 0 -> 0.5: TP 0.751 -> 0.774 (pedestrians
    # 0.30 -> 0.33 of their frames), id switches 60 -> 125 (crossing 51 -> 102), object ATE 0.286 -> 0.299 m.
    small_new_fraction: float = 0.0
    max_point_depth_m: float = 40.0
    # ORB budget of the keypoints on dynamic-class instances, a pass of its own after one that leaves the
    # instances out (the static keypoints are then `masked` mode's, orb.n_features for them alone), on pyramid
    # levels 0..features_max_level (the budgets of the levels above are dropped, not moved: 600 -> <= 404);
    # 0: one pass over the whole image, the instances keeping the keypoints that fall on them (~380 of 2000 on
    # sim crossing s0; the paper does not say which). On bench_dynamic's 20 sequences (traffic, following,
    # crossing, static s0-s4, 150 fr, 640x480), one pass -> 400 (levels 0-7) -> 800 (0-7) -> 400 (0-3) -> 600 (0-3):
    # object ATE 0.290 -> 0.262 -> 0.276 -> 0.243 -> 0.249 m, TP 0.753 -> 0.810 -> 0.841 -> 0.773 -> 0.809
    # (pedestrians 0.31 -> 0.42 -> 0.49 -> 0.32 -> 0.41 of their frames), id switches 47 -> 61 -> 64 -> 50 -> 62
    # (on unoccluded frames 6 -> 10 -> 6 -> 7 -> 7), mean ego ATE 0.0220 -> 0.0235 -> 0.0242 -> 0.0213 -> 0.0232 m
    # (`masked` 0.0296 m; dynamic <= masked on 13, 18, 18, 18, 14 of the 20: the per-sequence ego ATE moves by
    # up to 0.02 m between runs that differ in the objects alone).
    n_features: int = 600
    features_max_level: int = 3
    # Not in the paper: one more ORB pass (budget densify_features, 0: off) on the dynamic-class instances that
    # the passes before gave fewer than densify_below keypoints, on pyramid levels 0..densify_max_level (a
    # level-7 patch is ~110 px: on a 20 px object it describes the background). Measured with one pass for the
    # whole image (n_features=0), which at 640x480 gave a pedestrian within 30 m a median of 7 keypoints, 3 with
    # depth (sim crossing s0). Off: a coverage against accuracy trade. On the 8 bench_dynamic sequences (150 fr,
    # 640x480), 500 with stereo.row_search_instance_mask: TP 0.751 -> 0.824 (pedestrians 0.27 -> 0.39 of their
    # visible frames), object ATE 0.264 -> 0.353 m, id switches 27 -> 71 (crossing s1 12 -> 37: adjacent
    # pedestrians swap tracks), mean ego ATE 0.029 -> 0.025 m (traffic s0 0.021 -> 0.040); features + stereo
    # median 74 -> 106 ms per frame (traffic s0, one thread). Most added corners lie on the object's outline (so
    # do most first-pass ones: the sim's bodies are smoothly textured boxes), where they slide with the
    # background.
    densify_features: int = 0
    densify_below: int = 30
    densify_max_level: int = 2
    # Not in the paper: in `dynamic` mode the keypoints on dynamic-class instances get their orientation and
    # ORB descriptor again (after stereo matching) from the left image with every pixel off those instances
    # set to mid-grey, so that a keypoint on an object's outline (most of them: the sim's bodies are
    # smoothly textured) describes the object and not the background sliding behind it. On the 12
    # bench_dynamic sequences (traffic, following, crossing, static; seeds 0-2; 150 fr 640x480), off -> on:
    # id switches 53 -> 34 (paper's Table IV selection 13 -> 2, all on crossing s2), TP 0.732 -> 0.740,
    # object ATE 0.286 -> 0.301 m (single tracks move either way: crossing s0's far car 2 0.39 -> 2.85 m,
    # static s1 0.244 -> 0.163 m over the sequence), mean ego ATE 0.0267 -> 0.0222 m.
    masked_descriptors: bool = True
    # New object points farther than this from the median of the instance's points are dropped
    # (keypoints on the mask border that see the background). A box join whose instance's points, placed at the
    # track's prediction, have their median farther than this outside the box of the track's points re-anchors
    # the track on them (`ObjectTracker._reanchor`): following seeds 10-19 (150 fr, 640x480), object ATE 0.354 ->
    # 0.216 m (s15: an occluded lead car's pose ran off from 24 to 47 m on monocular matches, and points added
    # there kept its object frame 30 m off the body after it re-appeared); seeds 0-4 / 5-9 of the four scenarios
    # 0.229 -> 0.230 / 0.216 -> 0.218 m, id switches unchanged (42 / 20).
    max_point_spread_m: float = 5.0
    # Not in the paper: where the filter of a track measured within join_max_gap_s excludes the re-anchored position
    # (NIS above reanchor_gate_nis, chi2 3 dof 99 %, the position floor as its noise; inf: off), the box join keeps
    # the track at its prediction and adds none of the instance's points, and beyond reanchor_other_object_m no box
    # stage joins them (`BoxAssociation._jumps`: another object). Within 0.1-0.8 s of a measurement a prediction does
    # not run off by metres: crossing s41 f47 and s49 f97, trucks measured 0.1-0.2 s earlier (predicted sigma 0.07-0.09
    # m) re-anchored 6-8 m onto 6-7 keypoints of their far end (object ATE 0.236 / 0.374 m); crossing s80 f83-f99,
    # tracks measured 0.5-0.8 s earlier re-anchored 16-25 m onto other cars. The re-anchors the rule was made for pass
    # (following s15 f87: 13.2 m after 2.4 s unmeasured; crossing s92 f110: 9.1 m, sigma 7.3 m, a young track). Not
    # taken: no re-anchor within 0.8 s of a measurement (crossing s92 gt11 0.34 -> 2.69 m); the gate without the
    # distance tier (s80 gt6: an unoccluded id switch); refusing every gated join (unoccluded switches on s41 and s49:
    # the trucks' tracks lost them). bench_dynamic's scenarios (world 3, 150 fr, 640x480), 16 groups (as above),
    # inf -> 11.34, object ATE / id switches: crossing 40-54 0.248 -> 0.238 m / 14 -> 12, 70-84 0.280 -> 0.282 / 8
    # -> 6, 85-99 0.277 -> 0.274, 100-114 0.286 -> 0.285, 115-129 0.261 -> 0.252, traffic, crossing, static 35-39
    # 0.202 -> 0.187, 10-14 0.186 -> 0.187; the other groups unchanged; no unoccluded id switch, short gaps and TP
    # as they were (+-0.1 point).
    reanchor_gate_nis: float = 11.34
    reanchor_other_object_m: float = 10.0
    # (a) projection search under the constant-velocity prediction: radius (px at level 0, scaled by the keypoint
    # level), descriptor ratio; fewer matches than min_projection_matches -> (b). 6 (min_inliers) lets a track lost
    # for longer than max_velocity_gap_s (no (b) then) retake its object on a few matches (crossing s3's pedestrian
    # emerging after 1.4 s unmeasured: 4, 7, 10 matches in three frames). bench_dynamic's four scenarios (world 2,
    # 150 fr, 640x480), 8 -> 6 with the point vote's view test (`ObjectTracker._in_view`, below): seeds 0-4 short
    # gaps kept 29/33 -> 31/33, id switches 23 -> 20 (unoccluded 0 -> 0), object ATE 0.228 -> 0.239 m, TP 0.821 ->
    # 0.826, ego 0.0222 -> 0.0218 m; seeds 5-9 21/21 either way, 12 -> 13 (0 -> 0), 0.198 -> 0.204 m, 0.838 ->
    # 0.840, 0.0279 -> 0.0274 m; following seeds 10-19 2 -> 2 (0 -> 0), 0.173 -> 0.178 m, 0.810 -> 0.815, 0.0262 ->
    # 0.0257 m. 6 alone: an unoccluded switch on following s17 (the vote below); (a)'s 6-7 matches kept only when
    # (b) finds none: the same gaps, unoccluded switches on seeds 0-4 and 10-19.
    projection_radius: float = 12.0
    projection_nn_ratio: float = 0.9
    min_projection_matches: int = 6
    # (b) brute-force matching against the most overlapping instance (2D box IoU >= min_overlap_iou
    # with the object's last box): Hamming threshold and ratio test.
    min_overlap_iou: float = 0.1
    bf_max_distance: int = 64
    bf_nn_ratio: float = 0.8
    # Pose-only optimization: an object observation needs this many inliers; a pose implying a
    # speed above max_speed_mps since the last observation is rejected.
    min_inliers: int = 6
    max_speed_mps: float = 40.0
    # Opt-in (inf: off): a pose turned faster than max_turn_rate (rad/s) since the last observation is rejected too.
    # Pose-only rotations of thin or far objects flip (a pedestrian at 25 m turned by 159 deg in one frame, crossing
    # s6): on traffic and crossing seeds 0-9 (world 3, 150 fr, 640x480) 1 % of raw pose-only rotations imply > 4
    # rad/s, 0.1 % > 15, where no simulated object turns faster than 0.9 rad/s; over bench_dynamic's four scenarios 30
    # of ~30000 output steps turned by > 20 deg. inf -> 8 / 4 (6c2400e, seeds 0-4, 5-9, following 10-19): such steps
    # 30 -> 7 / 0, object RPE_r 1.62 -> 1.52 / 1.44 deg per frame, object ATE 0.224 / 0.176 / 0.178 -> 0.218 / 0.170 /
    # 0.177 m (4: 0.219 / 0.171 / 0.176), id switches 17 / 10 / 2 -> 17 / 7 / 2 (4: 18 / 8 / 2), unoccluded 0 / 2 / 0
    # -> 0 / 1 / 0 (4: 1 / 2 / 0), but ego ATE +0.9 mm on average over the 50 sequences (standard error 0.3 mm; worse
    # on 20, better on 8; +1.0 mm at 4), through the joint BA (traffic s8: a far car's changed pose moves the camera
    # by 2.3 cm at the next keyframe) without a mechanism found; the ego figures are issue 4's marginal ones, so it
    # stays off.
    max_turn_rate: float = float("inf")
    # The constant-velocity prediction turns at most this fast (rad/s): the angular velocity from two
    # consecutive pose-only rotations of a small or distant object is mostly noise (bench_dynamic's 20 sequences,
    # 150 fr 640x480: 90th percentile 0.9-1.9 rad/s by class where the sim's vehicles exceed 0.5 rad/s on 0.2 % of
    # their frames, 2 rad/s at most, and its pedestrians never turn), and a prediction turned by 0.5 rad
    # sends the projection search (a) and the overlap search (b) onto the neighbouring instance. inf -> 1.0 on the
    # 20 (one value tried): object ATE 0.249 -> 0.245 m, TP 0.809 -> 0.814, id switches 62 -> 50 (unoccluded
    # frames 7 -> 5; paper selection 2 -> 0), mean ego ATE 0.0232 -> 0.0226 m.
    max_angular_speed: float = 1.0
    # Its stereo residuals are [u, v, disparity], the disparity at sigma / pose_disparity_weight combined
    # with the depth uncertainty of the object point (0: ORB-SLAM2's isotropic [u, v, u_right], whose
    # disparity sigma is ~1.4 px at level 0 where the sub-pixel SAD gives ~0.1 px). The points of a distant
    # object share one depth that only the disparity measures; at ~1.4 px a point whose disparity is 1-2 px
    # off (3-6 m at 27 m) passes the chi2 test and drags the whole object. Measured on the 8 bench_dynamic
    # sequences (150 frames, 640x480), 0 -> 3: object ATE 0.324 -> 0.263 m, TP 0.749 -> 0.751, id switches
    # 26 -> 27, ego ATE 0.0281 -> 0.0285 m. Without the point term: 2, 3, 5 -> 0.278, 0.264, 0.285 m, but
    # points first placed far away were then rejected up close instead of fused (tests).
    pose_disparity_weight: float = 3.0
    # Robust initialization from 3D-3D matches (stereo depth) when no velocity is known: RANSAC
    # hypotheses and inlier distance.
    ransac_hypotheses: int = 64
    ransac_inlier_m: float = 0.3
    # Track ids: a new object whose matched keypoints are >= join_ratio (and >= min_join_matches)
    # points of one map object joins its track; else an instance whose box has IoU >= join_iou with
    # the motion-compensated box of an object observed within join_max_gap_s joins that track
    # (instance-to-instance association; its pose is then the registered constant-velocity prediction); else
    # the voted object, when no pose fitted the vote but the instance's box touches the object's last or
    # predicted box (not in the paper, whose vote joins without a pose test; before, such an instance started a
    # new track). bench_dynamic's four scenarios (world 2, 150 fr, 640x480), without -> with: seeds 0-4 short
    # gaps kept 28/31 -> 29/31, id switches 29 -> 29 (unoccluded 1 -> 1), object ATE 0.210 -> 0.212 m, ego
    # 0.0213 -> 0.0212 m; seeds 5-9 21/21 -> 21/21, 12 -> 11 (1 -> 1), 0.192 -> 0.193 m, 0.0266 -> 0.0269 m;
    # following seeds 10-19 identical. A vote counts only for a track with a point that projects into the image at
    # its prediction (`_in_view`): on following s17 a car that had left by the left border took, 0.8 s later, the
    # instance of the next car leaving there (a look-alike: its pose fitted the vote).
    join_ratio: float = 0.5
    min_join_matches: int = 6
    # Not in the paper: a vote does not take an instance from the track begun for the voted object while that one
    # was lost (its successor: confirmed, first observed after the voted track's last observation, seen in the
    # previous frame on a box that overlaps the instance's by >= join_iou); the successor keeps it by its box. A vote
    # there gave the object's old id back for a frame (crossing s84 gt4 f95-96, an unoccluded car: the old track,
    # lost at f89 with its origin 5 m off, voted at f95 with 24 inliers; its successor took the car back by box at
    # f96).
    # bench_dynamic's scenarios (world 3, 150 fr, 640x480), 16 groups (seeds 0-9 of the four scenarios, 10-39 of
    # traffic, crossing, static, crossing 40-129, following 10-39), without -> with: two sequences changed, crossing
    # s84 (unoccluded id switches 2 -> 0, object ATE 0.668 -> 0.606 m) and s64 (0.323 -> 0.309 m, TP 0.691 ->
    # 0.677); crossing 70-84 0.286 -> 0.282 m, id switches 10 -> 8, 55-69 0.274 -> 0.273 m, 13 -> 12.
    vote_spares_successor: bool = True
    join_iou: float = 0.3
    # A pedestrian's track often goes unmeasured for some frames (half its listed frames on crossing s0-s3 show <= 2
    # keypoints with stereo depth; 16 % of its pose-only optimizations fail on crossing s0/s2) and coasts on box
    # joins; a track neither measured nor box-joined for join_max_gap_s is box-joined no more (its instance starts a
    # new track). Box joins count as observations, as SORT's max_age counts from the newest matched detection. Counted
    # from the newest measured pose (before 141475a) -> now, bench_dynamic's scenarios (world 3, 150 fr, 640x480):
    # seeds 0-4 id switches 17 -> 17, object ATE 0.224 -> 0.225 m; seeds 5-9 10 -> 8 (unoccluded 2 -> 1: a 10 px
    # pedestrian box-joined 0.9 s after its last pose, crossing s9), 0.176 -> 0.177 m; following seeds 10-19 2 -> 1,
    # 0.178 -> 0.189 m (a rejoined car's coasted frames: following s10 gt10 0.31 -> 1.08 m); traffic, crossing,
    # static seeds 10-14 20 -> 17 (4 -> 3), 0.194 -> 0.197 m; TP and short gaps unchanged, ego ATE within 0.3 mm.
    # bench_dynamic's 20 sequences (traffic, following, crossing, static s0-s4, 150 fr, 640x480), 0.5 -> 0.8 -> 1.0
    # s: id switches 60 -> 45 -> 45 (crossing 51 -> 31 -> 30), object ATE 0.286 -> 0.291 -> 0.301 m (crossing s2
    # 0.47 -> 0.50 -> 0.71 m: a prediction running away), TP 0.751 -> 0.753 -> 0.754, ego ATE 0.0222 -> 0.0220 ->
    # 0.0225 m. With optim.objects.sigma_motion_xyz 0.201 as a noise control, 0.5 -> 0.8: 59 -> 46 id switches,
    # 0.294 -> 0.303 m. This and every other time window of the tracker and the BA's tail hold a gap of exactly their
    # length at any time of a sequence (`dynaslam2.time_windows.within`): at d8232ae a float difference of two
    # timestamps fell on either side of them. All 250 sequences (world 4, 150 fr, 640x480), without -> with: short
    # gaps lost 8 of 1016 -> 6 of 1018 (crossing s49, s108, s120 kept, s88 lost), id switches 102 -> 96 (unoccluded 0
    # either way), object ATE lower on 72 / higher on 103 (mean +1.1 mm), TP lower only on crossing
    # 100-114 (83.6 -> 83.5 %).
    join_max_gap_s: float = 0.8
    # Not in the paper: a track without a known velocity (its 3D prediction stands still) is box-joined by its last
    # box moved on at the image velocity of its boxes over the last box_velocity_window_s (SORT's constant-velocity
    # box; 0: the last box as it was), and a track box that lies >= join_contain inside the instance's box with an
    # IoU >= join_iou / 2 joins as if its IoU were join_iou (an object emerging from behind an occluder; 0: off).
    # bench_dynamic's four scenarios (150 fr, 640x480), both off -> on: seeds 0-4 short gaps kept 27 -> 29 of 32,
    # id switches 28 -> 23 (unoccluded 1 -> 0), object ATE 0.226 -> 0.229 m (rejoined tracks carry the points a
    # box join added at their prediction: crossing s2's emerging car 0.06 -> 0.29 m), TP 0.805 -> 0.807; seeds 5-9
    # 21 of 21 kept either way, id switches 13 -> 11 (unoccluded 2 -> 2), 0.214 -> 0.214 m, TP 0.829 -> 0.830;
    # following seeds 10-19 unchanged. Containment alone (seeds 0-4): 28 of 32, 25 switches, 0.229 m; the moving
    # box with a window of 0.3 s: 29 of 32, 24 switches (unoccluded 1), 0.230 m. The other way round too: an instance
    # box >= join_contain inside the track's (an object going behind an occluder; crossing s38 f111, a pedestrian
    # whose head alone stays in view: IoU 0.17, gate d2 7.5, a new track). One way -> both ways (world 3, 150 fr,
    # 640x480): crossing seeds 25-39 short gaps kept 91/95 -> 94/95, id switches 15 -> 7 (unoccluded 3 -> 0),
    # object ATE 0.286 -> 0.281 m; seeds 0-4 34/34 -> 33/33, 8 -> 9 (0), 0.228 -> 0.231 m; seeds 5-9 25/25 either
    # way, 3 -> 0, 0.172 -> 0.171 m; following 10-19 unchanged; traffic, crossing, static 10-14 53/53 -> 51/52, 6 ->
    # 8 (unoccluded 0 -> 3: crossing s14's pedestrian group, where a neighbour's pose took an instance at f121; the
    # joins the rule added there were all right), 0.195 -> 0.186 m; held-out 15-19 39/42 -> 41/42, 6 -> 6 (unoccluded
    # 0 -> 1: crossing s17's pedestrian group, a track passed between neighbours by containment joins), 0.198 -> 0.205
    # m; 20-24 25/28 -> 26/28, 4 -> 3 (0), 0.178 -> 0.176 m.
    box_velocity_window_s: float = 0.5
    join_contain: float = 0.8
    # Not in the paper: a velocity-known track that has left the view by an image border (its moved box clipped
    # from wholly outside the image while its 3D extent is still in view, its last box touching the border) is not
    # joined by its last box in the "box" stages: that box is where the next object entering by that border
    # appears (crossing s99 f77: a van gone by the left border at 14 m took the van entering there at 11 m and
    # coasted on its slivers, an unoccluded id switch). Off -> on (world 4, 150 fr, 640x480, dynamic mode against
    # 09cab22): crossing 40-129 changes on s99 only (id switches 1 -> 0, unoccluded 1 -> 0) and s57 (object ATE
    # 0.179 -> 0.151 m); crossing 0-39 on s12 (0.362 -> 0.229 m), s20 (switches 2 -> 1, short gaps kept 5 -> 6 of 6,
    # 0.293 -> 0.354 m: an extent join took the next car there a frame later either way), s34 (gaps 22 -> 21 of
    # 22, 0.268 -> 0.255 m: a van hidden 0.7 s behind a truck at the left border, its prediction run 63 px off the
    # image, reappeared inside its last box), s37 (0.272 -> 0.237 m, ego 0.019 -> 0.023 m); traffic, following and
    # static 0-39: identical. Over the groups: unoccluded id switches 2 -> 1, switches -2, short gaps kept equal.
    # Without the velocity-known and border conditions (any track whose moved box was clipped) it also refused a
    # young track of a car entering at the right border (crossing s82: a short gap lost). Refusing only a box
    # predicted outside by more than the prediction's margin (`_prediction_margin_px`) does not separate the two:
    # s99's gone van 6.9 px outside at a margin of 11.9, s34's van 63 px at 49.
    border_exit_drops_last_box: bool = True
    # Not in the paper: an instance with >= min_inliers close keypoints that no box reached join_iou with joins the
    # velocity-known track whose predicted box it overlaps and whose centre lies within box_gate_chi2 (chi2, 2 dof,
    # 95 %; 0: off) of the instance's box centre, in the position filter's predicted covariance projected into the
    # image plus a box-centre noise of box_gate_size_sigma of the instance's box size per axis (DeepSORT's
    # Mahalanobis gate; the pass's instances assigned jointly): a prediction a few pixels beside a narrow
    # pedestrian's box overlaps it too little for join_iou (crossing s3 gt25: moved box IoU 0.18, d2 2.4 at f109;
    # s14 gt11, a car whose last box an occluder had cut: 0.13 and 3.9 at f59). The overlap bounds the gate where
    # the projected covariance is large (a passing car, a box clipped to the image border, which it joined without
    # the overlap test: object ATE 0.197 -> 0.246 m on traffic, crossing, static s10-14). bench_dynamic's
    # scenarios (world 3, 150 fr, 640x480), off -> on (one value each): seeds 0-4 short gaps kept 33/34 -> 34/34,
    # id switches 11 -> 10 (unoccluded 0 -> 0), object ATE 0.235 -> 0.239 m, TP 0.824 -> 0.827, ego ATE 0.0217 ->
    # 0.0218 m; seeds 5-9 25/25 either way, 3 -> 3, 0.177 -> 0.176 m, 0.0268 -> 0.0269 m; following seeds 10-19
    # 2/2, 0 -> 0, 0.186 -> 0.190 m, 0.0262 m; traffic, crossing, static seeds 10-14 49/53 -> 50/53, 8 -> 9 (0 ->
    # 0), 0.197 -> 0.202 m, 0.0248 -> 0.0245 m. Of its joins on traffic, crossing and static seeds 0-14, 26 took
    # the instance of the object the track had last held, 10 another's (cars in a queue, pedestrians in pairs).
    # Not taken (seeds 10-14): re-anchoring a gate-joined track on its instance (11 switches, 0.205 m); a
    # non-degenerate predicted box instead of the overlap (51/53 kept, but 14 switches on seeds 0-4).
    # A pedestrian track without a velocity (its prediction stands still; its filter starts from
    # pedestrian_initial_speed_sigma) is gated too, by its last box, last of all: after the coasting instances' box
    # joins (crossing s10 gt25, a group's pedestrian hidden before its young track had a velocity, back beside its
    # last box: IoU 0.02, d2 0.26). Without -> with (world 3, 150 fr, 640x480): seeds 0-4, 5-9 and following 10-19
    # the same but crossing s6 (a pedestrian tracked 2 frames more); traffic, crossing, static seeds 10-14 short
    # gaps kept 52/53 -> 53/53, id switches 7 -> 6 (unoccluded 0 -> 0), object ATE 0.193 -> 0.195 m. Gated with the
    # velocity-known tracks, before the coasting pass, a young track took a neighbour's instance before its own,
    # coasting, instance could take it by overlap (traffic s3 and s4: seeds 0-4 id switches 8 -> 10). Vehicles'
    # young tracks are not gated: their 10 m/s prior (initial_speed_sigma) leaves only the box overlap to bound the
    # gate.
    box_gate_chi2: float = 5.991
    box_gate_size_sigma: float = 0.25
    # Not in the paper: an instance with >= min_inliers close keypoints that neither box stage nor the gate joined
    # joins the velocity-known vehicle track whose predicted 3D extent holds >= extent_min_fraction of the instance's
    # stereo points (the track's object-frame points, 5th to 95th percentile per axis, grown by extent_margin_m, at
    # its predicted pose; 0: off): an occluder that uncovers another part of a car moves its box against the
    # track's, while its points stay inside the car (crossing s29 f31, gt8: IoU 0, d2 22, 0.94 of its points
    # inside). Not for pedestrians: the margin is as wide as one, and a neighbour walking beside it fell inside
    # (crossing s28 f34). Both values first choices, not tuned. Without -> with, after the two-way containment test
    # above (world 3, 150 fr, 640x480): crossing seeds 25-39 short gaps kept 94/95 -> 95/95, id switches 7 -> 5
    # (unoccluded 0 -> 0), object ATE 0.281 -> 0.284 m; seeds 0-4 33/33 either way, 9 -> 6 (0), 0.231 -> 0.232 m;
    # seeds 5-9 25/25, 0 -> 0, 0.171 -> 0.174 m; following 10-19 unchanged; traffic, crossing, static 10-14 51/52 ->
    # 52/54, 8 (3) -> 5 (0), 0.186 -> 0.185 m; 15-19 41/42 either way, 6 (1) -> 6 (1), 0.205 -> 0.204 m; 20-24
    # 26/28 either way, 3 -> 3 (0), 0.176 -> 0.174 m. Its one wrong join seen (crossing s31 f16): a track whose
    # points had spread over 7.5 m, its prediction 6 m off its car.
    extent_min_fraction: float = 0.8
    extent_margin_m: float = 0.5
    # Not in the paper: in the "extent" stage, a vehicle track whose last box was cut by the left or right image
    # border has mapped only part of its length: its extent's longer horizontal axis is completed to this length of
    # its class on the side away from the camera (`BoxAssociation._length_completed`; 0: off). Traffic s39 f130: a
    # stopped van at the left border, its far end never mapped (points 0.3-3.4 m along its length), came out from
    # behind a nearer van by that end (3.3-5.9 m; 0.23 of its points in the extent) and began a new track. Lengths
    # at the short end of each class (the sim's cars 3.8-4.7 m, vans 4.8-5.4, trucks 7-9), first choices, not tuned.
    # Off -> on (world 4, 150 fr, 640x480; 242 sequences, all but crossing 121-129): two change, traffic s39
    # (short gaps kept 0 -> 1 of 1, TP 0.911 -> 0.930, object ATE 0.129 -> 0.135 m) and crossing s34 (21 -> 22 of 22,
    # 0.805 -> 0.811, 0.255 -> 0.268 m: gt14, a van hidden 0.7 s behind a truck at the left border); ego ATE
    # unchanged. Grown for every vehicle track, not only one cut by the border, it changed 6 of 43 sequences:
    # crossing s94 0.215 -> 0.321 m (a car 48 m away in mid-image, joined by the grown extent; four frames later its
    # track was 6 m off it), s64 +0.012 m; grown along the velocity instead of the longer axis it kept neither gap
    # (both vans stood still).
    border_cut_length_m: VehicleLengthsConfig = field(default_factory=VehicleLengthsConfig)
    # Not in the paper: a velocity-known vehicle track's pose claim on an instance with >= min_inliers close
    # keypoints is refused when less than this fraction of their stereo points lies in the track's predicted 3D
    # extent (as above; 0: off): crossing s62 f59, a car's track claimed by 7 of 18 matches the instance of another
    # car 4 m nearer, none of whose 101 points lay in its extent (an unoccluded id switch with vehicle_turn). 0.1 a
    # first choice; judged on fewer points it refused right claims (crossing s79 f82, one point): crossing 70-84
    # object ATE 0.308 m against 0.285 with the min_inliers condition. Figures with vehicle_turn's.
    claim_min_extent_fraction: float = 0.1
    # Not in the paper (opt-in): a velocity-known vehicle track's box join whose registration failed (the observation
    # is the prediction) adds none of the instance's keypoints as points when less than this fraction of their
    # stereo points (>= min_inliers) lies in the track's predicted 3D extent (as above; 0: off): points placed at a
    # prediction that lags a turn, or on another car that took the track by its last box at the image border
    # (crossing s12 f53: a van entering where another had left, 5 m deeper, driving the other way), disagree with
    # the track's, and the next pose-only optimizations fit the mixture. The track keeps the instance (and its id)
    # at its prediction, an unreported coasted observation. 0 -> 0.1 (world 3, 150 fr, 640x480; at 5a37f91), object
    # ATE / TP / short gaps kept: crossing 40-54 0.264 -> 0.264 m / 74.6 -> 74.5 % / 86 of 87 either way; 55-69
    # 0.277 -> 0.262 / 74.0 -> 73.9 / 85 of 85 -> 84 of 84; 70-84 0.285 -> 0.270 / 74.2 -> 74.0 / 106 of 108 -> 104
    # of 107; traffic, crossing, following, static seeds 0-4 0.232 -> 0.226, 5-9 0.176 -> 0.175; traffic, crossing,
    # static 10-14 0.199 -> 0.194, 15-19 0.201 -> 0.203, 20-24 0.184 -> 0.183 (27 -> 26 of 29 kept), 25-29 0.210 ->
    # 0.216 (31 -> 30 of 32); following 10-19 unchanged, 20-39 0.187 -> 0.186; no unoccluded id switch either way.
    # Not the default: three more short gaps lost, tracks that, kept from their car's points, coast off it
    # (crossing s20 gt8: a track that had taken the car by a wrong border join; s29 gt2: one whose rotation stood 90
    # degrees off after its first poses, so that its extent missed the car; s83 gt6 not examined).
    join_points_min_extent_fraction: float = 0.0
    # Not in the paper: no box stage joins a velocity-known vehicle track to an instance with >= min_inliers stereo
    # points of which less than join_min_extent_fraction lie in the track's predicted 3D extent while >=
    # join_owner_extent_fraction lie in another candidate track's (as above; 0: off). Crossing s120 f82: a car's
    # track predicted 25.5 m away took by its moved box (IoU 0.35) the instance of a nearer car at 19.4 m, which the
    # nearer car's own track's extent held (0.61; its moved box was off), before its own car's coasting instance:
    # the two cars swapped tracks. Vetoing every instance outside the extent refused right joins of objects that
    # reveal new parts (crossing s122 f65: a truck entering at the left border, outside its own track's extent):
    # crossing 115-129 unoccluded id switches 0 -> 7. bench_dynamic's scenarios (world 3, 150 fr, 640x480), 16 groups
    # (as above), 0 -> 0.1: five sequences changed, none for the worse: crossing 115-129 object ATE 0.265 -> 0.260 m,
    # id switches 13 -> 9 (s120 0.245 -> 0.203 m, 2 -> 0; s116 0.361 -> 0.321 m); 70-84 0.282 -> 0.280 m, short gaps
    # kept 108 -> 109 of 111 (s75 gt12); 100-114 0.287 -> 0.286 m, 10 -> 8 (s109); seeds 0-4 12 -> 8 (crossing s3);
    # no unoccluded id switch either way, TP within 0.1 point.
    join_min_extent_fraction: float = 0.1
    join_owner_extent_fraction: float = 0.5
    # Not in the paper: the track whose extent holds >= join_owner_extent_fraction of an instance vetoed from another
    # track (above) joins it in the "extent" stage, below extent_min_fraction (crossing s120 f82: the nearer car's
    # own track, its moved box off, its extent holding 0.61, lost its car to a new track). 16 groups (as above),
    # without -> with: four sequences changed, crossing s120 (gt4's short gap kept, 115-129 103 -> 104 of 104; object
    # ATE 0.203 -> 0.219 m, TP 0.840 -> 0.862), traffic s17 (0.189 -> 0.185 m; 15-19 0.201 -> 0.200), crossing s84
    # (0.606 -> 0.597) and s4 (0.266 -> 0.268); no id switch more.
    join_vetoed_to_owner: bool = True
    # Not in the paper (DeepSORT's appearance gallery): a person's track keeps the colour histograms (appearance_bins
    # per channel, over the instance's mask) of its instance at its last appearance_gallery observations; an instance
    # whose histogram lies further than appearance_max_distance (Bhattacharyya) from all of them is not the track's:
    # no pose claim, vote or box join of the track takes it (0: off). An instance of fewer than
    # appearance_min_pixels pixels is not judged; vehicles keep no gallery (a truck's front and side differ: with
    # them, crossing s41 lost its truck as it turned). Why: pedestrians side by side match each other's points and
    # boxes, and a track hopped to its neighbour (crossing s53 f92, s54 f67: unoccluded id switches) or box-joined
    # it. Logged on crossing seeds 40-54 (world 3, 150 fr, 640x480; distance to the histogram of the track's
    # previous instance): pose claims on the same object median 0.05, 99th percentile 0.27; box joins of the same
    # object 0.10 / 0.53 (partial views); claims and joins that moved a track to another object (56) median 0.66,
    # 55 above 0.4. 0.4 was chosen from these; the gallery size and pixel floor are first choices. Off -> 0.4:
    # crossing 40-54 id switches 40 -> 21 (unoccluded 2 -> 0), short gaps kept 80/87 -> 81/83, object ATE 0.252 ->
    # 0.271 m, TP 0.721 -> 0.725; crossing 55-69 23 (1) -> 19 (1), 82/82 either way, 0.282 -> 0.275 m; traffic,
    # crossing, static 15-19 6 (1) -> 6 (0), 41/42 -> 40/42 (crossing s15: a partly hidden pedestrian 0.40-0.41 from
    # its gallery lost its track), 0.203 -> 0.200 m; 20-24 3 (0) -> 1 (0), 26/28 -> 27/29, 0.174 m either way.
    # In the box stages' Hungarian assignment a person's gallery distance is added to the cost (-IoU, DeepSORT's
    # appearance term): crossing s82 f120, a pedestrian half hidden behind a neighbour in similar colours (0.40
    # from its gallery; its own instance 0.06) whose box overlapped its predicted box more (0.68 against 0.53) took
    # its track (an unoccluded id switch). Measured alone: crossing 70-84 switches 9 (1 unoccluded) -> 8 (0);
    # crossing 40-54 and traffic/crossing/static 10-14 and 15-19 identical.
    appearance_max_distance: float = 0.4
    appearance_bins: int = 4
    appearance_min_pixels: int = 30
    appearance_gallery: int = 10
    # A pose claim or point vote also skips an instance that lies appearance_margin closer to another active track's
    # gallery than to the track's own (a look-alike within appearance_max_distance: crossing s14 f121, two
    # pedestrians in dark clothes 0.40-0.53 apart, a hop there and back; box joins keep the absolute test only).
    # 0.2 a first choice. 0 -> 0.2: traffic, crossing, static 10-14 id switches 8 -> 6 (unoccluded 2 -> 0); crossing
    # 40-54 21 -> 23 (0 -> 0; s51: two tracks of one pedestrian, each refused it for the other's closer gallery);
    # every other figure of seeds 0-4, 5-9, 10-14, 15-19, 20-24, crossing 40-54 and 55-69 unchanged.
    appearance_margin: float = 0.2
    # The margin rule in the box stages too (box joins keep the absolute test only when off): an instance that lies
    # appearance_margin closer to another active track's gallery is no box candidate of the track (a look-alike's
    # track lost beyond the join window still counts, and the appearance stage then re-identifies it). Crossing s126
    # f103 (world 4): a person's track coasting on a sliver took by its box the instance of its neighbour 10 px away
    # (0.39 from its gallery, 0.06 from the neighbour's lost track's) while its own person got a new track: two
    # unoccluded id switches (f105, f109). Measured (world 4, 316ee79's code otherwise): crossing s126 4 switches (2
    # unoccluded) -> 0, s110 3 (1) -> 1 (0), s6 2 (1) -> 0 (a swap of two people at f129), object ATE 0.184 ->
    # 0.186, 0.168 -> 0.167 and 0.215 -> 0.217 m: four of world 4's six unoccluded switches; s72 and s99 (other
    # causes) unchanged; crossing 40-54 identical (0.230 m, 81.0 %, 12 switches, 99 of 101 gaps), 55-69 0.260 ->
    # 0.256 m, TP 80.4 -> 80.3 %, 21 switches and 91 of 92 gaps either way; 100-114 0.231 m, 83.1 % and 131 of 133
    # either way, switches 11 (1 unoccluded) -> 8 (0); 115-129 0.221 m and 105 of 107 either way, TP 81.8 -> 81.9 %,
    # switches 14 (2) -> 10 (0). The other groups (seeds 0-14, fresh 15-39, following 10-39, crossing 70-99) rerun
    # with it: identical but for s6 (above), crossing s39 (3 switches -> 0, object ATE 0.194 -> 0.187 m, ego ATE
    # 0.016 -> 0.019 m) and crossing 70-84 (0.286 -> 0.287 m, TP 80.5 -> 80.6 %, switches 19 -> 17); short gaps
    # unchanged everywhere. World 4 in all: unoccluded id switches 6 -> 2, id switches 125 -> 111. On by default
    # after these runs.
    appearance_margin_box_joins: bool = True
    # DeepSORT's appearance cascade for lost tracks: an instance that no earlier stage took joins the person's track
    # lost within max_lost_s whose gallery lies within appearance_reid_distance of its histogram (Hungarian on the
    # distance) and whose predicted box centre gates it (box_gate_chi2); the track is re-anchored on the instance
    # when the registration finds no match (its prediction after a second or two is metres off: without, crossing
    # s44's pedestrian, back after 1.6 s with a 4 m off prediction, got 5.1 m of ATE). Crossing s64: a pedestrian
    # 1.3 s in the left image border, beyond the box window, kept its id. 0.2 a first choice (same-object claims:
    # 90th percentile 0.12). Off -> 0.2 (after appearance_margin): crossing 40-54 id switches 23 -> 19 (unoccluded
    # 0 -> 0), short gaps kept 81/83 -> 83/85, object ATE 0.271 -> 0.276 m, TP 0.725 -> 0.729; traffic, crossing,
    # static 10-14 6 -> 4 (0), 53/55 -> 55/55, 0.182 -> 0.190 m, 0.824 -> 0.828; crossing 55-69 19 (1) -> 15 (0),
    # 82/82 -> 84/84, 0.275 -> 0.276 m; 15-19 6 -> 2 (0), 40/42 -> 41/42, 0.200 -> 0.204 m; 20-24 1 (0) and 27/29
    # either way, 0.174 -> 0.175 m, TP 0.807 -> 0.809. Seeds 0-4 and 5-9 not rerun with it.
    appearance_reid_distance: float = 0.2
    # The appearance stage also over the instances with too few keypoints (coasting: "coast-appearance", within
    # pedestrian_coast_max_s of the track's last observation); such a join stands only when the instance's mask
    # measures the track (`ObjectTracker._mask_register`, its validation gate at mask_gate_nis), else the instance
    # joins nothing. A person back from behind an occluder as a sliver that overlaps neither its moved box nor its last
    # one keeps its id (crossing s62 gt22 f34: its legs below the moved box of the head it was last seen by, 0.8 s
    # before). Without the mask's condition (first 23 crossing sequences) a sliver of a neighbour 5 m behind, alike in
    # colour, took a person's track for 12 frames (crossing s5 f10-22, object ATE 0.154 -> 0.472 m). World 4 (150 fr,
    # 640x480), all 250 sequences, off -> on: short gaps lost 11 of 1014 -> 8 of 1016 (crossing s29, s51, s62 kept),
    # id switches 111 -> 102 (unoccluded 0 either way), object ATE lower on 27 / higher on 34 (mean +0.8 mm), TP never
    # lower on a group; crossing's 90 seeds 0.252 -> 0.253 m, TP 81.5 -> 81.8 %, switches 71 -> 67; fresh 25-29 0.156
    # -> 0.168 m (static s25 gt25, a person standing at 39 m whose track was begun at 12 m and whose mask-centre body
    # point was learned 28 m off, f36: its slivers' centre measurements agree with that point and joined, 0.17 ->
    # 3.1 m); every group's mean ego ATE within 0.5 mm (crossing 115-129 0.0153 -> 0.0148 m).
    appearance_reid_coasting: bool = True
    # A track joined by box IoU is translated from its prediction onto the instance's keypoints that
    # match its points (3D offsets), when at least register_min_matches agree: an offset agrees when it lies
    # within register_chi2 (3 dof) of the registered shift in its stereo uncertainty (along the viewing ray the
    # two depths', 1 px of disparity at the keypoint's level; across it 1 px at that level), and the shift is the
    # information-weighted mean of the agreeing offsets; the registered position is then the filter's measurement.
    # It replaces matches within ransac_inlier_m of the median offset, with the prediction kept as the pose: at
    # 30 m (7.5 px of disparity at 640x480) depths scatter by metres and a far car crossing at 1 m per frame was
    # never registered, so it coasted at its stale prediction until join_max_gap_s lapsed (crossing s2 gt1, an
    # unoccluded id switch). bench_dynamic's four scenarios (world 2, 150 fr, 640x480), old -> new: seeds 0-4
    # short gaps kept 26/31 -> 28/31, id switches 25 -> 29 (unoccluded 1 -> 1: crossing s2 gt1 kept, a 47 px
    # pedestrian lost for 3 frames in the same sequence), object ATE 0.212 -> 0.210 m, TP 0.805 -> 0.803, ego ATE
    # 0.0215 -> 0.0213 m; seeds 5-9 20/21 -> 21/21, 13 -> 12 (1 -> 1), 0.190 -> 0.192 m, 0.828 -> 0.830,
    # 0.0288 -> 0.0266 m; following seeds 10-19 object ATE 0.164 -> 0.156 m, TP 0.792 -> 0.790, ego 0.0275 -> 0.0274.
    register_min_matches: int = 3
    register_chi2: float = 7.815
    # An instance with fewer than min_inliers close keypoints keeps (by box IoU) a track observed within coast_max_s at
    # its constant-velocity prediction, without new points (0: never); in each box stage after the instances with enough
    # keypoints (the moved-box stage before the last-box one: crossing s47, a farther car's instance took a hidden car's
    # track by its last box while the hidden car's own instance, 3 keypoints, overlapped its moved box; traffic,
    # crossing, static 15-19 and 20-24, crossing 55-69 and 70-84 unchanged but for chaotic per-sequence changes,
    # crossing 40-54 short gaps kept 84 -> 85 of 85). Such a coasted observation keeps the track's id but is not
    # reported (unless report_coast_s, below): its pose is the prediction alone. 0.3 s (3 frames at 10 Hz; the one value
    # measured besides 0.5 at f1173f5) bridges a pedestrian truncated by the left image border, where no stereo reaches,
    # for 1.3 s (crossing s7). bench_dynamic's scenarios (world 3, 150 fr, 640x480), 0 -> 0.3 s: seeds 0-4 id switches
    # 17 -> 11 (unoccluded 0 -> 0), TP 0.819 -> 0.824, object ATE 0.225 -> 0.235 m, short gaps kept 33/33 -> 33/34, ego
    # ATE 0.0220 -> 0.0217 m; seeds 5-9 8 -> 3 (1 -> 0), 0.832 -> 0.834, 0.177 -> 0.177 m, 25/25, 0.0265 -> 0.0268 m;
    # following seeds 10-19 1 -> 0, 0.817 -> 0.823, 0.189 -> 0.186 m, 2/2, 0.0256 -> 0.0262 m; traffic, crossing, static
    # seeds 10-14 17 -> 8 (3 -> 1), 0.813 -> 0.820, 0.197 -> 0.197 m, 48/52 -> 50/53, 0.0249 -> 0.0255 m. Without the
    # order (any instance first, in id order): 13 / 7 / 0 / 9 id switches; reporting every coasted pose (no
    # report_coast_s bound): TP 0.857 / 0.855 / 0.843 / 0.846, object ATE 0.246 / 0.199 / 0.220 / 0.203 m (following
    # s15's lead car, hidden but for a sliver, coasted 2.95 m off).
    coast_max_s: float = 0.3
    # coast_max_s for a pedestrian's instance: a person who walked behind a car or another person comes out as a
    # sliver with a few keypoints (at 15-20 m, where the crossing people walk) for longer than a car does, and its box
    # against the track's moved box keeps the track (crossing s74 gt22: hidden 0.5 s, then a sliver whose box
    # overlapped the moved one by 0.6 began a new track); the mask measurement (mask_depth_classes) then measures it.
    # 0.3 -> 0.8 s (join_max_gap_s, the window of an instance with keypoints), with the left-the-view rule judged by
    # the 3D extent for every class (`BoxAssociation.predicted_box`; people's now by the box), crossing 40-54 / 55-69
    # / 70-84 / 85-99 / 100-114 / 115-129: TP 80.3 / 80.0 / 79.7 / 79.9 / 83.4 / 81.0 -> 80.7 / 80.0 / 80.4 / 80.4 /
    # 83.9 / 81.6 %, id switches 21 / 20 / 17 / 12 / 11 / 20 -> 19 / 19 / 13 / 12 / 11 / 15, object ATE 0.260 / 0.300
    # / 0.309 / 0.300 / 0.315 / 0.290 -> 0.267 / 0.285 / 0.313 / 0.308 / 0.324 / 0.300 m (more coasted people
    # reported, pedestrian_report_coast_s), short gaps lost 8 of 684 -> 8 of 698; over the 90 seeds TP 80.7 -> 81.2
    # %, object ATE 0.296 -> 0.300 m. With the rule as it is, every group: README.
    pedestrian_coast_max_s: float = 0.8
    # Not in the paper: a coasting instance (too few close keypoints) that keeps a track by its box measures the
    # track's position from its mask alone (`tracking.mask_measurement`): the mask's disparity as a whole
    # (`features.stereo.instance_disparities`: NCC of the left mask along its rows of the right image, peak NCC >=
    # mask_min_ncc, (1 - peak) < mask_uniqueness x (1 - the best NCC 2 px or more away); RGB-D: the depth image's
    # median over the mask), and the mask's centroid against that of the track's points predicted inside it, gated
    # by the position filter at mask_gate_nis. The observation is measured (reported, and its box moves the track
    # on); instances of >= mask_min_pixels pixels without any keypoint take part too. Mask disparities on sim
    # crossing s40-s42 (every third frame, dynamic instances of 30-2000 px, the GT depth's median over the mask as
    # reference; 1028 instances): uniqueness 0.8 -> 0.6 found 89 -> 80 %, over 1 px off 3.0 -> 0.7 %, median |error|
    # 0.17 px (hence mask_disparity_sigma_px 0.3). ~0.3 ms per instance. bench_dynamic's scenarios (world 3, 150 fr,
    # 640x480), off -> on: crossing 40-54 object ATE 0.282 -> 0.277 m, TP 0.732 -> 0.748, id switches 15 -> 15 (0
    # unoccluded), short gaps kept 85/85 -> 86/87; crossing 55-69 0.275 -> 0.275 m, 0.727 -> 0.738, 15 -> 12 (0),
    # 84/84 -> 85/85; seeds 0-4 0.228 -> 0.235 m, 0.831 -> 0.841, 5 -> 5 (0), 34/34 -> 38/38, ego ATE 0.0222 m either
    # way. Not taken: an instance too small for an object by its keypoints (min_new_points) beginning one on its mask
    # (at its centroid and depth, where its keypoints agree with that depth and no unseen track's box touches it):
    # crossing 40-54 TP 0.792 at object ATE 0.321 m and 32 id switches, 55-69 0.792 / 0.359 m / 34 (1 unoccluded).
    # A person's (mask_depth_classes) box join whose keypoints do not register is measured by its mask's centre too,
    # against the body point the first such measurement found (`ObjectTracker._mask_centre_register`): without, a
    # walking person's box joins carried a still prediction on (crossing s114 gt20 3.13 m). With fuse_chi2, a3e6a50 ->
    # 80aae80 (every group): crossing 40-54 / 55-69 / 70-84 / 85-99 / 100-114 / 115-129 object ATE 0.258 / 0.285 /
    # 0.313 / 0.308 / 0.324 / 0.300 -> 0.260 / 0.294 / 0.299 / 0.287 / 0.300 / 0.281 m (90 seeds 0.298 -> 0.287, lower
    # on 50), TP 81.2 % either way (55-69 79.96 -> 80.34), id switches 86 -> 91 with one unoccluded (s99 gt1: README);
    # the mixed groups' object ATE within -0.017 / +0.009 m. Against the origin itself (the mask's centre taken as
    # the origin): s41 gt19 0.06 -> 0.97 m, its origin, 3 m behind the person from its first points at 35 m, moved
    # onto the body mid-track. Vehicles measured against their points (the coasting rule): worse on 17 of 21 seeds.
    # A coasting person's mask that its points cannot place (fewer than register_min_matches points found again
    # inside it: a walking person's points are seldom found again) is measured by its centre as well: crossing s92
    # gt24, in full view at 17 m, had run 1-3 m off on a stale prediction for 1.7 s, its mask measurements then
    # refused by the gate, and lost its track at a brief occlusion. At 3e7a486 without -> with, every group (250
    # sequences; README): crossing s72's unoccluded switch gone (none left), short gaps lost 14 of 1011 -> 11 of 1014
    # (kept s3, s21, s92, one of s90's two; lost s22's), object ATE lower on 66, higher on 97 (mean -2.4 mm; 25-29
    # 0.204 -> 0.156 m, crossing 40-54 0.230 -> 0.244 m). Its cost: a centre measurement moves the origin with the
    # visible part of a partly hidden person (s119 gt21, standing behind a car: 1 m up, 0.18 -> 0.71 m).
    mask_measurement: bool = True
    mask_min_pixels: int = 30
    mask_min_ncc: float = 0.5
    mask_uniqueness: float = 0.6
    mask_disparity_sigma_px: float = 0.3  # the disparity's sigma in the position measurement
    mask_centroid_sigma: float = 0.15  # the centroid's sigma per image axis, as a fraction of the mask box's size
    mask_gate_nis: float = 11.34  # a mask measurement's validation gate (chi2, 3 dof, 99 %) against the filter
    # Tracks unseen for longer than this are no longer matched (occlusions up to it keep the id).
    max_lost_s: float = 2.0
    # Velocity known (prediction (a) used) only if the last two observations are this close in time.
    max_velocity_gap_s: float = 0.5
    # Weak object tracking (III-D): an object on an instance with >= weak_min_features keypoints but
    # < weak_max_tracked tracked points, and fewer than weak_tracked_ratio of its keypoints, asks for a
    # keyframe (at most every kf_min_frames frames).
    weak_min_features: int = 20
    weak_max_tracked: int = 20
    weak_tracked_ratio: float = 0.5
    kf_min_frames: int = 2
    # At a keyframe every tracked object, not only the weak ones of III-D, gains points from its instance's free
    # close keypoints, so that its model covers what is seen (a pose claim adds no points: a long vehicle's model
    # otherwise holds the part seen when its track began). Points gained where the object was not weak do not count
    # as tracked in the weak test (`ObjectPoints.coverage`); counted, objects stop asking for keyframes and the ego
    # ATE rises with the lost keyframes (seeds 15-19 0.0217 -> 0.0308 m). Not in the paper. Off -> on (world 3, 150
    # fr, 640x480; at ba499c1), object ATE / TP / ego ATE: traffic, crossing, following, static seeds 0-4 0.232 ->
    # 0.204 m / 84.0 -> 85.2 % / 0.0233 -> 0.0181 m, 5-9 0.176 -> 0.157 / 84.6 -> 85.2 / 0.0275 -> 0.0271; traffic,
    # crossing, static 10-14 0.199 -> 0.187 / 83.8 -> 85.0 / 0.0266 -> 0.0209, 15-19 0.201 -> 0.189 / 83.4 -> 84.4 /
    # 0.0217 -> 0.0207, 20-24 0.184 -> 0.163 / 81.8 -> 82.7 / 0.0250 -> 0.0240, 25-29 0.210 -> 0.188 / 84.4 -> 85.3 /
    # 0.0217 -> 0.0199; crossing 40-54 0.264 -> 0.267 / 74.6 -> 76.1 / 0.0167 -> 0.0167, 55-69 0.277 -> 0.270 / 74.0
    # -> 75.1 / 0.0184 -> 0.0148, 70-84 0.285 -> 0.307 / 74.2 -> 75.6 / 0.0160 -> 0.0151; following 10-19 0.169 ->
    # 0.146 / 83.1 -> 84.0 / 0.0261 -> 0.0247, 20-39 0.187 -> 0.176 / 82.1 -> 83.0 / 0.0282 -> 0.0275; short gaps
    # lost 6 either way (other ones). Not the default: id switches on unoccluded tracks, none before, on crossing
    # s26 (a car's own track re-taking it two frames after a new track began on it) and s84 (back and forth between
    # a track that had taken the car by a border join and the car's own), and crossing 70-84 above 0.3 m (s75 gt6
    # 1.1 -> 4.8 m: a turning car's model grown at wrong poses after a 7-inlier pose claim lost its rotation).
    kf_points_all_objects: bool = False
    # A keyframe's BA with objects (run when an object is weak) optimizes every object observed at the keyframe
    # with points, not only the weak ones of III-D: the points kf_points_all_objects adds at pose-only poses are
    # refined with the poses and velocities (eq. 3-5) over the 2 s tail. Both on against both off (at 8099e04), object
    # ATE / TP / ego ATE: seeds 0-4 0.232 -> 0.192 m / 84.0 -> 84.9 % / 0.0233 -> 0.0187 m, 5-9 0.176 -> 0.156 /
    # 84.6 -> 85.3 / 0.0275 -> 0.0273; 10-14 0.199 -> 0.186 / 83.8 -> 84.8 / 0.0266 -> 0.0202, 15-19 0.201 -> 0.182
    # / 83.4 -> 84.2 / 0.0217 -> 0.0193, 20-24 0.184 -> 0.181 / 81.8 -> 82.8 / 0.0250 -> 0.0263, 25-29 0.210 ->
    # 0.214 / 84.4 -> 85.1 / 0.0217 -> 0.0191; crossing 40-54 0.264 -> 0.260 / 74.6 -> 76.1, 55-69 0.277 -> 0.235 /
    # 74.0 -> 75.1, 70-84 0.285 -> 0.309 / 74.2 -> 75.4, 85-99 0.297 -> 0.299 / 75.8 -> 77.0; following 10-19 0.169
    # -> 0.155, 20-39 0.187 -> 0.166; following 0-39 ego 0.0286 -> 0.0275 (masked 0.0297); no id switch on an
    # unoccluded track (off: one, crossing s99); short gaps lost on the fresh groups 9 -> 6. Not the default yet:
    # crossing 70-84 above 0.3 m, and the BA per keyframe on traffic s0 / s1 152 / 91 ms (off 62 / 51; bench_dynamic
    # run alone, fps 0.40x static against 0.50x), over the 80 ms target.
    ba_all_objects: bool = False
    # Output (objects.jsonl, tracks.txt, the environment's observation): a track is reported from its
    # min_output_observations-th observation on (1: from its first), as multi-object trackers confirm tracks (SORT's
    # min_hits, DeepSORT's n_init). Not in the paper. A track created for an object whose own track claims it again a
    # frame later (a pedestrian emerging from occlusion, a far car whose box join lapsed) was an id switch there and
    # back. bench_dynamic's four scenarios (150 fr, 640x480), 1 -> 2: seeds 0-4 id switches 42 -> 28 (unoccluded
    # 4 -> 1), TP 0.817 -> 0.805, object ATE 0.230 -> 0.226 m; seeds 5-9 20 -> 13 (4 -> 2), TP 0.844 -> 0.829, 0.218 ->
    # 0.214 m; following seeds 10-19 2 -> 0, TP 0.787 -> 0.774, 0.216 -> 0.211 m. The estimates are unchanged.
    # A tentative track (fewer observations) that finds nothing in a frame is deleted with its points, as DeepSORT
    # deletes a tentative track that misses a frame: on crossing s10 a track made at f35 for a pedestrian back after
    # 1 s, whose old track a vote re-acquired at f36, took it back at f37 by its box (an unoccluded id switch).
    # bench_dynamic's four scenarios (world 3, 150 fr, 640x480), without -> with: 64 of 65 sequences (seeds 0-9,
    # following 10-19, traffic / crossing / static 10-14) identical; on crossing s10 unoccluded switches 1 -> 0, short
    # gaps kept 50 -> 49 of 53 on seeds 10-14 (chaos: another pedestrian, stopping as it was hidden for 0.3 s, had
    # a velocity estimate of 2.3 m/s against 0.5 before, so its predicted box fell beside its instance, IoU 0.48 ->
    # 0), object ATE 0.197 -> 0.197 m. The box association matches the confirmed tracks (>= this many observations)
    # through its whole cascade before the tentative ones (DeepSORT's order): crossing s51 f62, a car back from a
    # 0.3 s occlusion had got a tentative track from its partial view at f61, which then outbid its own track by IoU
    # (0.48 against 0.31). Measured alone: crossing 40-54 id switches 19 -> 16, short gaps kept 83 -> 84 of 85, object
    # ATE 0.276 -> 0.285 m (two tracks kept longer carry more error); traffic/crossing/static 20-24 27 -> 28 of 29;
    # crossing 70-84 and 15-19 unchanged but for ATE (0.289 -> 0.291 m on 70-84).
    min_output_observations: int = 2
    # Opt-in, not in the paper: a coasted observation (an instance box-associated with the track but not measured:
    # its pose is the track's prediction) is reported when the track was measured (by points or by its mask) within
    # report_coast_s before it (0: never, as SORT reports matched tracks only; an agent may want the short
    # predictions as object permanence). Measured with bench_dynamic's scenarios (world 3, 150 fr, 640x480, objects
    # within 30 m), 0 -> 0.3 s: TP seeds 0-4 0.841 -> 0.889, 5-9 0.846 -> 0.886, traffic / crossing / static 10-14
    # 0.839 -> 0.879, 15-19 0.834 -> 0.879, 20-24 0.821 -> 0.862, following 10-19 0.831 -> 0.857, `crossing` alone
    # 40-54 0.748 -> 0.788, 55-69 0.738 -> 0.776, 70-84 0.741 -> 0.783; object ATE 0.235 -> 0.251, 0.179 -> 0.193,
    # 0.188 -> 0.202, 0.205 -> 0.217, 0.177 -> 0.191, 0.175 -> 0.186, 0.277 -> 0.287, 0.275 -> 0.285, 0.287 -> 0.304
    # m (above the 0.3 m target: every sequence's predictions add error, crossing s72 +0.09 m); no unoccluded id
    # switch; the ego motion is unchanged (output only). Not the default while crossing 70-84 crosses 0.3 m and
    # `crossing` stays below 80 % either way.
    report_coast_s: float = 0.0
    # report_coast_s for a pedestrian's track: a person walks on at its constant-velocity prediction (a vehicle turns
    # and brakes: crossing s40 gt5's car coasted 4 m off in 1.5 s). Offline on crossing 40-54 with mask_depth_classes
    # (the same run's coasted observations reported or not), TP / object ATE: none 77.1 % /
    # 0.251 m; people within 0.3 / 0.5 / 1 / 2 s 79.4 / 79.7 / 80.0 / 80.2 % at 0.255-0.257 m; every class within 0.3
    # s 81.5 % at 0.268 m, within 1 s 83.1 % at 0.283 m. Measured, 0 -> 1 s (with mask_depth_classes, before the
    # left-the-view rule of `BoxAssociation.predicted_box`), crossing 40-54 / 55-69 / 70-84 / 85-99 / 100-114 /
    # 115-129: TP 77.1 / 76.5 / 76.7 / 77.5 / 80.5 / 77.8 -> 80.3 / 80.0 / 79.7 / 80.0 / 83.4 / 81.0 %, object ATE
    # 0.251 / 0.293 / 0.296 / 0.290 / 0.304 / 0.283 -> 0.260 / 0.303 / 0.308 / 0.305 / 0.316 / 0.292 m, and three
    # unoccluded id switches (s61, s90, s97: a person's sliver at the right border, coasted by the track of the person
    # who had left there a frame before; that rule removed them).
    pedestrian_report_coast_s: float = 1.0
    # Object-point culling: seen in view this often with a found ratio below cull_found_ratio.
    cull_min_visible: int = 5
    cull_found_ratio: float = 0.25
    # Bundle adjustment with objects on keyframes (III-D); False: object poses from tracking only (the static
    # local BA on every keyframe). Measured on bench_dynamic's 20 sequences (traffic, following, crossing, static
    # s0-s4, 150 fr, 640x480) at 0c2f0b9, True -> False: object ATE 0.286 -> 0.268 m, mean ego ATE 0.0222 ->
    # 0.0217 m, id switches 60 -> 60, TP 0.751 -> 0.749: the joint BA does not (yet) improve the ego motion
    # here, and the tracker's filtered poses and depth-fused points track the objects better than its estimates.
    ba: bool = True
    # The static local BA also runs on keyframes where both the camera and an object are weak, before the
    # joint BA. Not a paper step (ORB-SLAM2 runs its local BA on every keyframe). Needed by the exact joint
    # form (optim.objects.static_reduced=false), whose LM (optim.ba_*, 5 + 10 from lambda 1, 1 % stop) leaves
    # the static part unconverged otherwise: 150 frames 640x480 seed 0, off -> on: ego ATE traffic 0.056 ->
    # 0.020 m, following 0.022 -> 0.017 m. The reduced form (the default) solves the static terms' quadratic
    # model, which is what the static BA's single LM iteration does: on bench_dynamic's 12 sequences (traffic,
    # following, crossing, static s0-s2, 150 fr 640x480), on -> off: mean ego ATE 0.0273 -> 0.0268 m, object
    # ATE 0.297 -> 0.287 m, TP 0.731 -> 0.732, id switches 61 -> 65 (crossing s1/s2 +3/+1), median BA per
    # keyframe lower on 9 of 12 (one linearization of the static terms instead of two). Keyframes inserted
    # for an object only get the paper's object-weak BA alone (III-D: static points constant): running the
    # static local BA there too gave, on the 8 sequences of bench_dynamic (150 fr, 640x480, same run), the same
    # mean ego ATE (0.0270 against 0.0271 m without), object ATE 0.395 against 0.382 m, median BA per keyframe
    # 157 against 125 ms.
    static_ba_first: bool = False
    # A keyframe inserted for a weak object only triangulates new static points with its neighbours (True), or not
    # (False: the paper, III-D, "this key frame would not introduce new static map points"; its close stereo points
    # are still created, as on every keyframe). With objects.ba the static local BA does not run there, so its
    # triangulated points were never refined before the next frames tracked against them. bench_dynamic's 20
    # sequences (traffic, following, crossing, static s0-s4, 150 fr, 640x480), True -> False: mean ego ATE 0.0247 ->
    # 0.0226 m (within the run-to-run spread of 0.0218-0.0247 m; dynamic <= masked on 12 -> 16 of 20), camera RPE
    # 0.551 -> 0.536 cm per frame, object ATE 0.224 -> 0.222 m, TP 0.818 -> 0.816, id switches 48 -> 50 (unoccluded
    # 5 -> 5), median BA per keyframe 35 -> 32 ms. Without the stereo points too: ego 0.0262 m, camera RPE 0.611 cm
    # per frame (worse).
    object_keyframe_triangulates: bool = False
    # Not in the paper: between BAs, each inlier stereo observation of an object point is averaged
    # into its position in the object frame, weighted by its depth information (1 px disparity at its
    # level), so that points created far away take the depth of closer views.
    fuse_points: bool = True
    # With fuse_points, only the shape is averaged in: the depth-weighted mean of the updates (a common
    # shift of all points, i.e. of the object frame along the body: what an error of the pose the
    # observations were placed with produces) is removed, so the object-frame origin stays on the body
    # instead of drifting with the pose errors (errors along the viewing axis, several metres at 30 m).
    fuse_shape_only: bool = True
    # With fuse_points, an observation whose disparity differs from its point's (placed at the measured pose) by more
    # than this chi2 (1 dof, 99 %) of the two variances is not fused: a wrong stereo match up close (4.2 m for a car at
    # 34 m, crossing s84 f2) carries a thousand times a far point's depth information, and fuse_shape_only's common
    # shift then moved every other point of the car 10 m; its origin, left 10 m off the body, swung with each rotation
    # error (its object ATE 2.57 -> 0.20 m; crossing s84 0.595 -> 0.505 m; on 57 of crossing's seeds 4 sequences changed,
    # mean object ATE 0.3046 -> 0.3029 m, TP unchanged).
    fuse_chi2: float = 6.635
    # Not in the paper: a constant-velocity Kalman filter of each object-frame origin between BAs
    # (white acceleration accel_sigma m/s^2; pose-only position covariance from its stereo Jacobian,
    # 1 px at level 0, plus position_floor_m; unknown initial speed initial_speed_sigma m/s).
    filter: bool = True
    accel_sigma: float = 1.5
    position_floor_m: float = 0.05
    initial_speed_sigma: float = 10.0
    # A new pedestrian track's velocity prior instead (m/s per axis; people walk at ~1.4 m/s): with 10 m/s the first
    # two positions of a young pedestrian track (noisy at 15-25 m, a partly hidden body's visible part shifting) set
    # its velocity (a standing one at 20 m with 0.1 m of noise: 2.5 m/s rms, 0.74 with 1 m/s). Sets (seeds 0-4 / 5-9
    # / following 10-19 / traffic, crossing, static 10-14; with `first_claim`'s tie rule), 10 -> 1.0: object ATE
    # 0.239 / 0.176 / 0.190 / 0.202 -> 0.228 / 0.172 / 0.164 / 0.193 m, id switches 10 / 3 / 0 / 9 -> 8 / 3 / 0 / 7
    # (none unoccluded), short occlusions kept 34/34, 25/25, 2/2, 50/53 -> 34/34, 25/25, 2/2, 52/53, paper selection
    # 0.076 / 0.085 / 0.076 / 0.080 -> 0.080 / 0.086 / 0.075 / 0.080 m, ego 0.0218 / 0.0269 / 0.0262 / 0.0245 ->
    # 0.0223 / 0.0268 / 0.0261 / 0.0250 m (within the chaotic spread); fresh following seeds 20-39 0.197 -> 0.184 m.
    # The prior as the stationary law of a pedestrian velocity reverting to rest (an integrated Ornstein-Uhlenbeck
    # velocity, Singer's model, with accel_sigma's driving noise at 10 Hz: tau 8 s) gave about the same (0.229 /
    # 0.170 / 0.163 / 0.190 m, 11 / 4 / 0 / 6 switches, 51/52 kept on 10-14); with tau 2 s (4x the noise, without
    # the tie rule) 0.231 / - / - / 0.195 m and 12 / - / - / 13 switches, 2 unoccluded.
    pedestrian_initial_speed_sigma: float = 1.0
    # Not in the paper, with `filter`: a constant-angular-velocity filter of each object's rotation (white
    # angular acceleration angular_accel_sigma rad/s^2; pose-only rotation covariance from its stereo Jacobian,
    # the translation marginalized, plus rotation_floor_rad; unknown initial turn rate initial_angular_speed_sigma
    # rad/s). The angular velocity from two consecutive pose-only rotations is mostly noise (see max_angular_speed).
    # bench_dynamic's 20 sequences (traffic, following, crossing, static s0-s4, 150 fr, 640x480), off -> on with
    # angular_accel_sigma 0.5 / 1.0 / 2.0: object RPE_r 4.32 -> 2.24 / 2.35 / 2.49 deg per frame (paper
    # selection 2.48 -> 1.21 / 1.34 / 1.62), object ATE 0.245 -> 0.232 / 0.228 / 0.229 m, TP 0.814 -> 0.817,
    # id switches 50 -> 44 / 51 / 49, mean ego ATE 0.0227 -> 0.0242 / 0.0242 / 0.0236 m (within the run-to-run
    # spread of the ego ATE, 0.0218-0.0242 m over variants that change the objects only). The BA's rotation and
    # turn rate of the newest observation were then noisier than the filter's (optim.objects.ba=false: RPE_r
    # 1.66 deg per frame): its write-back keeps the filter's there (mapping.objects.write_back), RPE_r 2.24 ->
    # 1.84 (paper selection 1.21 -> 1.10), object ATE 0.232 -> 0.224 m, id switches 44 -> 48, ego 0.0247 m.
    rotation_filter: bool = True
    angular_accel_sigma: float = 0.5
    rotation_floor_rad: float = 0.02
    initial_angular_speed_sigma: float = 0.5
    # Not in the paper, with `filter`: a vehicle's position filter turns its predicted velocity at the rotation's
    # (capped) angular velocity, a coordinated turn of known rate (`object_filter.predict_state`), as the pose
    # prediction (eq. 5) already turns; the filter's straight prediction overrode the turned one wherever an
    # observation was a prediction, so a car coasting through a turn left its arc (crossing s75 gt6: 4-5 m off the
    # car after a right turn, object ATE 3.1 -> 1.1 m). World 3, 150 fr, 640x480, off -> on (with
    # claim_min_extent_fraction 0.1; against the session-39 runs): crossing 40-54 / 55-69 / 70-84 object ATE 0.277 /
    # 0.275 / 0.287 -> 0.264 / 0.277 / 0.285 m, TP 74.8 / 73.8 / 74.1 -> 74.6 / 74.0 / 74.2 %, id switches 15 / 12 /
    # 10 -> 18 / 12 / 6 (none unoccluded), tracks over 2 m off 8 -> 6; seeds 0-4 / 5-9 / 10-14 / 15-19 / 20-24 /
    # 25-29 0.235 / 0.179 / 0.188 / 0.205 / 0.177 / 0.211 -> 0.232 / 0.176 / 0.199 / 0.201 / 0.184 / 0.210 m (10-14:
    # crossing s12 gt4, a van joined at the image border where another had left, 0.50 -> 2.50 m), TP within 0.4
    # points, no unoccluded switch, short gaps lost 6 -> 6 (others), ego 0.0222 / 0.0274 / 0.0257 / 0.0225 / 0.0268
    # / 0.0213 -> 0.0233 / 0.0275 / 0.0266 / 0.0217 / 0.0250 / 0.0217 m; following 10-19 / 20-39 0.175 / 0.186 ->
    # 0.169 / 0.187 m. Neutral on the group means (the chaotic spread); taken as the consistent model. Alone, without
    # the claim test: crossing 0.262 / 0.272 / 0.280 m, but two unoccluded switches on 55-69 (crossing s62).
    vehicle_turn: bool = True
    # Not in the paper, with `filter`: the classes whose rotation the tracker does not measure. A pose-only pose of
    # such an object keeps the predicted rotation (the last one turned at its capped w_o) and is moved so that its
    # points' centroid stays where the pose-only put it; the rotation filter takes the prediction (the BA still
    # refines the poses, eq. 2-5). A pedestrian is a thin body that 6-10 keypoints see from 15-30 m: its pose-only
    # rotation is noise, which the rotation filter can turn into a spin that moves the object-frame origin by metres
    # (people begun at 30-33 m from their mask's depth: crossing s42 gt22, 7 m away with 36 points, 38 -> 175 deg off
    # within 0.8 s). bench_dynamic's scenarios (world 3, 150 fr, 640x480), () -> (pedestrian,): object ATE seeds 0-4
    # / 5-9 / 10-14 / 15-19 / 20-24 / 25-29 0.227 / 0.175 / 0.194 / 0.210 / 0.183 / 0.209 -> 0.222 / 0.178 / 0.186 /
    # 0.201 / 0.180 / 0.209 m, crossing 40-54 / 55-69 / 70-84 / 85-99 0.264 / 0.264 / 0.287 / 0.301 -> 0.248 / 0.274 /
    # 0.286 / 0.277 m, following 10-19 / 20-39 0.169 / 0.186 -> 0.164 / 0.183 m (the paper's selection lower on 10
    # of 12); TP within 0.2 points; id switches on unoccluded tracks 0 -> 2 (crossing s84 gt4 f95-96, a car: its old
    # track, lost at f89 with its origin 5 m off, re-takes it by a point vote for one frame from the track begun for
    # it at f91; none since vote_spares_successor); short gaps lost on the fresh groups 9 -> 11. On two groups first
    # run after it was set, crossing 100-114 and traffic, crossing, static 30-34: 0.315 / 0.179 -> 0.287 / 0.172 m, TP
    # 78.3 / 83.6 -> 78.6 / 83.6 %, unoccluded switches 1 (crossing s111 gt24) / 0 -> 0 / 0, short gaps 122 of 122, 31
    # of 31 either way.
    translation_only_classes: tuple[str, ...] = ("pedestrian",)
    # Validation gate: a pose-only position whose NIS against the filter's prediction exceeds this
    # (chi2, 3 dof) is rejected as an association outlier; inf: no gate.
    gate_nis: float = float("inf")

    def validate(self) -> None:
        for name in ("min_new_points", "min_projection_matches", "min_inliers", "min_join_matches",
                     "register_min_matches", "ransac_hypotheses", "kf_min_frames", "densify_below",
                     "min_output_observations", "appearance_min_pixels", "appearance_gallery", "mask_min_pixels"):
            if getattr(self, name) < 1:
                raise ConfigError(f"objects.{name}: expected a positive integer, got {getattr(self, name)}")
        if not 1 <= self.appearance_bins <= 16:
            raise ConfigError(f"objects.appearance_bins: expected an integer in [1, 16] (bins per colour channel), "
                              f"got {self.appearance_bins}")
        for name in ("translation_only_classes", "mask_depth_classes"):
            unknown = [c for c in getattr(self, name) if c not in DYNAMIC_CLASSES]
            if unknown:
                raise ConfigError(f"objects.{name}: expected class names among "
                                  f"{', '.join(sorted(DYNAMIC_CLASSES))}, got {unknown[0]!r}")
        if self.min_inliers < 3:
            raise ConfigError(f"objects.min_inliers: expected >= 3, got {self.min_inliers}")
        if not (-1.0 <= self.mask_min_ncc <= 1.0 and 0.0 < self.mask_uniqueness <= 1.0):
            raise ConfigError(f"objects: expected mask_min_ncc in [-1, 1] and mask_uniqueness in (0, 1], got "
                              f"{self.mask_min_ncc}, {self.mask_uniqueness}")
        for name in ("max_point_depth_m", "max_point_spread_m", "projection_radius", "max_speed_mps", "max_turn_rate",
                     "max_angular_speed", "ransac_inlier_m", "max_lost_s", "max_velocity_gap_s", "join_max_gap_s",
                     "accel_sigma", "position_floor_m", "initial_speed_sigma", "pedestrian_initial_speed_sigma",
                     "gate_nis", "angular_accel_sigma", "rotation_floor_rad", "initial_angular_speed_sigma",
                     "register_chi2", "fuse_chi2", "mask_disparity_sigma_px", "mask_centroid_sigma", "mask_gate_nis",
                     "reanchor_gate_nis", "reanchor_other_object_m", "mask_depth_max_m"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"objects.{name}: expected > 0, got {getattr(self, name)}")
        for name in ("coast_max_s", "pedestrian_coast_max_s", "report_coast_s", "pedestrian_report_coast_s",
                     "box_velocity_window_s", "box_gate_chi2", "box_gate_size_sigma", "extent_margin_m",
                     "pose_disparity_weight", "n_features", "features_max_level", "densify_features",
                     "densify_max_level"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"objects.{name}: expected >= 0, got {getattr(self, name)}")
        for name in ("min_overlap_iou", "join_ratio", "join_iou", "cull_found_ratio", "bf_nn_ratio",
                     "projection_nn_ratio", "weak_tracked_ratio", "small_new_fraction", "join_contain",
                     "extent_min_fraction", "claim_min_extent_fraction", "join_points_min_extent_fraction",
                     "join_min_extent_fraction", "join_owner_extent_fraction", "appearance_max_distance",
                     "appearance_margin",
                     "appearance_reid_distance"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"objects.{name}: expected in [0, 1], got {getattr(self, name)}")


@dataclass
class SlamConfig:
    """Root of the SLAM configuration."""

    mode: Mode = "dynamic"
    orb: ORBConfig = field(default_factory=ORBConfig)
    stereo: StereoConfig = field(default_factory=StereoConfig)
    matcher: MatcherConfig = field(default_factory=MatcherConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    objects: ObjectsConfig = field(default_factory=ObjectsConfig)  # object tracking (`dynamic` mode)


def load_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> SlamConfig:
    """Defaults, then the YAML file at `path` (if any), then `--set key=value` overrides."""
    layers = [load_yaml(path)] if path is not None else []
    layers.append(parse_overrides(list(overrides)))
    return build(SlamConfig, *layers)
