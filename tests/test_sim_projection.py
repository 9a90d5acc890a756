"""The rendered images agree with the written ground truth and calibration, to the pixel.

One short sequence is generated and read back through `dynaslam2.io` (calib.txt, poses, objects);
the checks use only the pinhole model of the written calibration, except the depth check, which
casts rays in a rebuilt (deterministic) world through the pixel centres.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from dynaslam2.classes import CLASS_IDS, INSTANCE_CLASS_FACTOR
from dynaslam2.io.sequence import open_sequence
from sim.generate import generate_sequence
from sim.groundtruth import box_corners
from sim.render import RenderConfig, StereoRenderer
from sim.scenarios import load_scenario
from sim.world import build_world, camera_intrinsics

SIZE = "400x300"
FRAMES = 10


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("traffic", [f"frames={FRAMES}", f"image_size={SIZE}", "seed=3"])


@pytest.fixture(scope="module")
def seq(scenario, tmp_path_factory):
    out = tmp_path_factory.mktemp("proj") / "seq"
    generate_sequence(scenario, out, progress=False)
    return open_sequence(out)


def _mask_extent(instances: np.ndarray, mots_id: int) -> np.ndarray | None:
    """(u0, v0, u1, v1) continuous extent of an instance mask (pixel centres at integers)."""
    rows, cols = np.nonzero(instances == mots_id)
    if len(rows) == 0:
        return None
    return np.array([cols.min() - 0.5, rows.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5])


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def test_projected_gt_boxes_cover_instance_masks(seq):
    cam = seq.camera
    checked, ious = 0, []
    for i in range(len(seq)):
        frame = seq[i]
        T_c_w = np.linalg.inv(seq.gt_T_w_c[i])
        for obj in seq.gt_objects(i):
            mots = CLASS_IDS[obj.cls] * INSTANCE_CLASS_FACTOR + obj.track_id
            extent = _mask_extent(frame.instances, mots)
            assert extent is not None, f"frame {i}: listed object {mots} has no pixel"
            # The GT 2D box is the visible mask's box (inclusive pixel indices).
            np.testing.assert_allclose(obj.box2d, extent + [0.5, 0.5, -0.5, -0.5])
            T_c_o = T_c_w @ obj.T_w_o
            X_c = box_corners(np.array([obj.dims]))[0] @ T_c_o[:3, :3].T + T_c_o[:3, 3]
            if np.any(X_c[:, 2] <= 0.1):
                continue
            uv = cam.project(X_c)
            proj = np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
            # Every mask pixel centre lies inside the projected box (it covers the mask).
            assert extent[0] + 0.5 >= proj[0] - 1e-3 and extent[2] - 0.5 <= proj[2] + 1e-3, (i, mots, extent, proj)
            assert extent[1] + 0.5 >= proj[1] - 1e-3 and extent[3] - 0.5 <= proj[3] + 1e-3, (i, mots, extent, proj)
            big = min(extent[2] - extent[0], extent[3] - extent[1]) >= 15
            if obj.visible_fraction == 1.0 and obj.truncation == 0.0 and big:
                ious.append(_iou(proj, extent))
                checked += 1
    assert checked >= 5, f"only {checked} unoccluded, untruncated objects of >= 15 px to check"
    assert min(ious) >= 0.9, f"IoU of projected GT box vs mask box: min {min(ious):.3f} over {checked}"


def _grey(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


def _textured_object_pixels(frame, half: int) -> tuple[np.ndarray, np.ndarray]:
    """(v, u) of pixels whose (2*half+1)^2 patch lies on one object, is textured and nearly fronto-constant in depth."""
    inst = frame.instances.astype(np.int64)
    depth = frame.depth.astype(np.float64)
    H, W = inst.shape
    k = 2 * half + 1
    centre = (slice(half, H - half), slice(half, W - half))
    same = (sliding_window_view(inst, (k, k)) == inst[centre][..., None, None]).all(axis=(2, 3)) & (inst[centre] > 0)
    depth_w = sliding_window_view(depth, (k, k))
    flat = depth_w.max(axis=(2, 3)) - depth_w.min(axis=(2, 3)) < 0.02 * depth[centre]
    grey = _grey(frame.left)
    grad = np.zeros_like(grey)
    grad[:, 1:-1] = np.abs(grey[:, 2:] - grey[:, :-2])
    v, u = np.nonzero(same & flat & (grad[centre] > 8))
    return v + half, u + half


def _ncc_disparity(left: np.ndarray, right: np.ndarray, v: np.ndarray, u: np.ndarray, d0: np.ndarray,
                   half: int, search: int) -> tuple[np.ndarray, np.ndarray]:
    """Subpixel disparity by NCC of (2*half+1)^2 patches over integer shifts round(d0) +- search, then a parabola.

    Returns (disparity, peak NCC); NaN where the best shift is at the search border.
    """
    offs = np.arange(-half, half + 1)
    patch_l = left[v[:, None, None] + offs[:, None], u[:, None, None] + offs[None, :]]  # (P, k, k)
    shifts = np.round(d0).astype(np.intp)[:, None] + np.arange(-search, search + 1)  # (P, S)
    cols = (u[:, None] - shifts)[:, :, None, None] + offs[None, None, None, :]
    rows = v[:, None, None, None] + offs[None, None, :, None]
    patch_r = right[rows, cols]  # (P, S, k, k) by broadcasting
    a = patch_l - patch_l.mean(axis=(1, 2), keepdims=True)
    b = patch_r - patch_r.mean(axis=(2, 3), keepdims=True)
    ncc = (a[:, None] * b).sum(axis=(2, 3)) / np.sqrt((a[:, None] ** 2).sum(axis=(2, 3)) * (b ** 2).sum(axis=(2, 3)) + 1e-12)
    best = ncc.argmax(axis=1)
    rows_idx = np.arange(len(v))
    inner = np.clip(best, 1, 2 * search - 1)
    c0, c1, c2 = ncc[rows_idx, inner - 1], ncc[rows_idx, inner], ncc[rows_idx, inner + 1]
    sub = 0.5 * (c0 - c2) / np.where(c0 - 2 * c1 + c2 < 0, c0 - 2 * c1 + c2, -1e-12)
    disparity = np.where((best > 0) & (best < 2 * search), shifts[rows_idx, inner] + sub, np.nan)
    return disparity, c1


def test_disparity_of_object_pixels_is_fx_b_over_z(seq):
    """Object pixels matched left -> right (subpixel NCC) sit at disparity fx*B/Z, Z from the GT depth image."""
    cam = seq.camera
    half, search = 4, 3
    rng = np.random.default_rng(0)
    errors = []
    for i in range(0, len(seq), 3):
        frame = seq[i]
        v, u = _textured_object_pixels(frame, half)
        d_gt = cam.bf / frame.depth[v, u].astype(np.float64)
        keep = u - np.round(d_gt) - search - half >= 0
        v, u, d_gt = v[keep], u[keep], d_gt[keep]
        pick = rng.choice(len(v), size=min(300, len(v)), replace=False)
        d, peak = _ncc_disparity(_grey(frame.left), _grey(frame.right), v[pick], u[pick], d_gt[pick], half, search)
        good = np.isfinite(d) & (peak > 0.9)
        errors.append(d[good] - d_gt[pick][good])
    errors = np.concatenate(errors)
    assert len(errors) >= 100, f"only {len(errors)} well-textured object pixels matched"
    med = np.median(np.abs(errors))
    within = np.mean(np.abs(errors) < 0.5)
    assert med < 0.2, f"median |disparity - fx*B/Z| = {med:.3f} px"
    assert abs(np.mean(errors)) < 0.1, f"disparity bias {np.mean(errors):.3f} px"
    assert within >= 0.95, f"only {within:.1%} of {len(errors)} matches within 0.5 px of fx*B/Z"


def test_rig_is_rectified_with_the_written_baseline(seq, scenario):
    """MuJoCo's right camera sits exactly at +B along the left camera's x axis, same orientation and fovy."""
    world = build_world(scenario)
    m, d = world.model, world.data
    cam = seq.camera
    for t in (0.0, 0.7):
        world.set_time(t)
        left, right = (m.camera(name).id for name in ("left", "right"))
        R_l, R_r = d.cam_xmat[left].reshape(3, 3), d.cam_xmat[right].reshape(3, 3)
        np.testing.assert_allclose(R_l, R_r, atol=1e-12)
        np.testing.assert_allclose(R_l.T @ (d.cam_xpos[right] - d.cam_xpos[left]), [cam.baseline, 0, 0], atol=1e-9)
        np.testing.assert_allclose(d.cam_xpos[left], world.ego_T_m_c(t)[:3, 3], atol=1e-9)
    assert m.cam_fovy[left] == m.cam_fovy[right]
    fx, fy, cx, cy = camera_intrinsics(scenario)
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [fx, fy, cx, cy], rtol=1e-12)


def test_depth_png_matches_ray_casting(seq, scenario):
    """Depth PNG (mm) equals the z of a ray cast through each pixel centre, within 1 mm up to 20 m.

    Compared on box and mesh geoms (road and sidewalk ribbons, buildings, vehicle bodies): cylinders and
    ellipsoids are drawn as polygons (RenderConfig.mesh_slices), so their rendered depth departs from the
    analytic surface by up to r*(1 - cos(pi/slices)).
    """
    world = build_world(scenario)
    cam = seq.camera
    groups = np.array([1, 1, 1, 0, 0, 0], np.uint8)  # the geom groups the renderer draws
    n_checked = 0
    for i in (0, len(seq) - 1):
        t = float(seq.timestamps[i])
        world.set_time(t)
        T_m_c = world.ego_T_m_c(t)
        depth = seq[i].depth.astype(np.float64)
        vv, uu = np.mgrid[0:cam.height:2, 0:cam.width:2]
        rays_c = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones_like(uu, float)], -1).reshape(-1, 3)
        rays_m = rays_c @ T_m_c[:3, :3].T
        norm = np.linalg.norm(rays_m, axis=1)
        n = len(rays_m)
        dist = np.zeros(n)
        geomid = np.zeros(n, np.int32)
        mujoco.mj_multiRay(world.model, world.data, T_m_c[:3, 3].copy(), (rays_m / norm[:, None]).ravel(), groups,
                           1, -1, geomid, dist, None, n, 1e6)
        hit = geomid >= 0
        z_ray = np.where(hit, dist / norm, 0.0)  # the ray's z component is 1 per unit of rays_c
        z_png = depth[vv.ravel(), uu.ravel()]
        in_range = ~hit | (z_ray < 65.0)  # uint16 millimetres cover 65.535 m
        gtype = world.model.geom_type[np.maximum(geomid, 0)]
        box = hit & (gtype == mujoco.mjtGeom.mjGEOM_BOX)
        # Where the ray first meets a curved geom, the drawn polygon (inscribed) may show what lies behind
        # its silhouette instead (possibly beyond 65.5 m, written as 0): hit or not is exact elsewhere.
        exact = in_range & (~hit | box | (gtype == mujoco.mjtGeom.mjGEOM_MESH))
        np.testing.assert_array_equal(z_png[exact] > 0, hit[exact], err_msg=f"frame {i}: depth vs ray hits")
        near = (box | (hit & (gtype == mujoco.mjtGeom.mjGEOM_MESH))) & (z_ray <= 20.0)
        err = np.abs(z_png[near] - z_ray[near])
        assert err.max() <= 1e-3, f"frame {i}: depth error up to {err.max() * 1e3:.2f} mm within 20 m"
        n_checked += int(near.sum())
    assert n_checked > 5000


def test_amodal_windows_and_full_renders_agree(scenario):
    """Amodal counts from packed crop windows equal full-image single-actor renders, and visible <= amodal."""
    world = build_world(scenario)
    K = camera_intrinsics(scenario)
    W, H = scenario.image_size
    with StereoRenderer(world, W, H) as fast, StereoRenderer(world, W, H, RenderConfig(amodal_crop=False)) as full:
        for t in (0.0, 0.6):
            world.set_time(t)
            T_m_c = world.ego_T_m_c(t)
            a = fast.render(T_m_c, K, right=False)
            b = full.render(T_m_c, K, right=False)
            visible = a.visible_px > 0
            assert visible.sum() >= 3
            np.testing.assert_array_equal(a.amodal_px, b.amodal_px)
            assert np.all(a.visible_px[visible] <= a.amodal_px[visible])
            assert np.all(a.amodal_px[~visible] == 0)


def test_silhouettes_are_anti_aliased_and_labels_stay_exact(scenario):
    """The default colour passes blend a silhouette's pixels (a camera integrates over each pixel) while the
    instance ids and depth equal those of a render without multisampling."""
    world = build_world(scenario)
    K = camera_intrinsics(scenario)
    W, H = scenario.image_size
    with StereoRenderer(world, W, H) as smooth, StereoRenderer(world, W, H, RenderConfig(msaa_samples=0)) as aliased:
        n_edge = n_blended = 0
        for t in (0.0, 0.6):
            world.set_time(t)
            T_m_c = world.ego_T_m_c(t)
            a = smooth.render(T_m_c, K, right=True)
            b = aliased.render(T_m_c, K, right=True)
            np.testing.assert_array_equal(a.instances, b.instances)
            np.testing.assert_array_equal(a.depth, b.depth)
            edge = np.zeros(a.instances.shape, bool)  # pixels with a horizontal neighbour of another instance
            step = a.instances[:, 1:] != a.instances[:, :-1]
            edge[:, 1:] |= step
            edge[:, :-1] |= step
            changed = np.any(a.left != b.left, axis=2)
            n_edge += int(edge.sum())
            n_blended += int((changed & edge).sum())
            assert changed.mean() < 0.15, f"t={t}: {changed.mean():.0%} of the pixels changed, not only edges"
            assert np.any(a.right != b.right)
    assert n_edge > 200
    assert n_blended > 0.3 * n_edge, f"{n_blended} of {n_edge} silhouette pixels blended"


def test_gt_velocities_match_pose_differences(seq):
    """v_w and w_w (in the sequence world) equal central differences of the GT object poses."""
    from dynaslam2.geometry.se3 import so3_log

    dt = float(seq.timestamps[1] - seq.timestamps[0])
    n_checked = n_moving = 0
    for i in range(1, len(seq) - 1):
        before = {o.track_id: o for o in seq.gt_objects(i - 1)}
        after = {o.track_id: o for o in seq.gt_objects(i + 1)}
        for obj in seq.gt_objects(i):
            if obj.track_id not in before or obj.track_id not in after:
                continue
            a, b = before[obj.track_id].T_w_o, after[obj.track_id].T_w_o
            v_fd = (b[:3, 3] - a[:3, 3]) / (2 * dt)
            w_fd = so3_log(b[:3, :3] @ a[:3, :3].T) / (2 * dt)
            np.testing.assert_allclose(obj.v_w, v_fd, atol=0.05 + 0.02 * np.linalg.norm(v_fd))
            np.testing.assert_allclose(obj.w_w, w_fd, atol=0.02)
            n_checked += 1
            n_moving += int(np.linalg.norm(v_fd) > 1.0)
    assert n_checked >= 20 and n_moving >= 5, (n_checked, n_moving)
