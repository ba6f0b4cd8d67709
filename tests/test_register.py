"""pcdof.stages.register: depth re-sampled into the colour camera.

References: closed-form depth of planes and boxes (rays from cv2.undistortPoints, not from
pcdof.geometry), cv2.registerDepth, and real captured RGB-D data with calibration.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

import pcdof.stages.register as register_mod
from pcdof.camera import Intrinsics, RGBDFrame, Rig
from pcdof.errors import InputError
from pcdof.plans import RegisterPlan, plan_register
from pcdof.stages.register import needs_registration, register_depth, reproject_depth, warmup
from pcdof.stages.register import reproject as register_reproject
from pcdof.stages.register import tasks as register_tasks
from pcdof.stages.register.rig import rig_constants

DATA = Path(__file__).resolve().parent.parent / "data" / "real"

DEPTH_DIST = (-0.0999, 0.3907, 0.0019, -0.0019, -0.5103)  # NYU Kinect v1 depth camera
COLOR_DIST = (0.2080, -0.5861, 0.0007, 0.0010, 0.4986)  # NYU Kinect v1 colour camera


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warmup()


def rot(yaw_deg=0.0, pitch_deg=0.0, roll_deg=0.0) -> np.ndarray:
    a, b, c = (math.radians(v) for v in (yaw_deg, pitch_deg, roll_deg))
    ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return ry @ rx @ rz


def make_rig(depth_size=(160, 120), color_size=(160, 120), *, fd=145.0, fc=131.0, ddist=(), cdist=(),
             t=(-0.05, 0.002, 0.001), angles=(0.6, -0.3, 0.2)) -> Rig:
    dw, dh = depth_size
    cw, ch = color_size
    depth = Intrinsics(dw, dh, fd, fd * 1.002, dw / 2 - 0.7, dh / 2 + 0.4, ddist)
    color = Intrinsics(cw, ch, fc, fc * 0.998, cw / 2 + 0.9, ch / 2 - 0.3, cdist)
    T = np.eye(4)
    T[:3, :3] = rot(*angles)
    T[:3, 3] = t
    return Rig(color, depth, T)


def rays_cv2(intr: Intrinsics) -> np.ndarray:
    """(H*W, 3) rays (x/z, y/z, 1) of the pixel centres, undistorted by OpenCV."""
    vv, uu = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)
    xy = cv2.undistortPoints(uv, intr.K, intr.dist_coeffs, criteria=criteria).reshape(-1, 2)
    return np.column_stack([xy, np.ones(len(xy))])


def depth_camera_rays(rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """Origin and directions, in the colour frame, of the depth pixels (t along them = depth z)."""
    T = np.asarray(rig.T_color_from_depth)
    return T[:3, 3], rays_cv2(rig.depth) @ T[:3, :3].T


def cast_plane(origin, dirs, n, d) -> np.ndarray:
    """t where origin + t * dirs meets the plane n . X = d."""
    return (d - np.dot(n, origin)) / (dirs @ n)


def cast_box(origin, dirs, lo, hi) -> np.ndarray:
    """t of the first hit of an axis-aligned box (slab method), inf on a miss."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (np.asarray(lo) - origin) / dirs
        tb = (np.asarray(hi) - origin) / dirs
    tmin = np.nanmax(np.minimum(ta, tb), axis=1)
    tmax = np.nanmin(np.maximum(ta, tb), axis=1)
    return np.where((tmax >= tmin) & (tmin > 0), tmin, np.inf)


def interior(mask: np.ndarray, margin_px: int) -> np.ndarray:
    """Pixels of *mask* at least *margin_px* from its edge and from the image border."""
    m = np.pad(mask, 1).astype(np.uint8)
    k = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
    return cv2.erode(m, k).astype(bool)[1:-1, 1:-1]


# ---------------------------------------------------------------------------------------------


class TestPlane:
    @pytest.mark.parametrize(
        "rig",
        [
            make_rig(ddist=DEPTH_DIST, cdist=COLOR_DIST),
            make_rig(),
            # Kinect v2 proportions: a coarse depth grid magnified about 2.9x into the colour image
            make_rig((128, 106), (480, 270), fd=91.4, fc=265.2, ddist=(0.09, -0.27, 0, 0, 0.09),
                     cdist=(0.02, -0.05, 0, 0, 0.015)),
        ],
        ids=["nyu-distortion", "pinhole", "magnified"],
    )
    def test_registers_to_analytic_depth(self, rig):
        n = np.array([0.25, -0.15, 1.0])
        n /= np.linalg.norm(n)
        d = 1.8  # plane n . X = d in the colour frame
        o, dirs = depth_camera_rays(rig)
        depth = cast_plane(o, dirs, n, d).reshape(rig.depth.shape).astype(np.float32)
        truth = cast_plane(np.zeros(3), rays_cv2(rig.color), n, d).reshape(rig.color.shape)
        out = reproject_depth(depth, rig)
        assert out.shape == rig.color.shape and out.dtype == np.float32
        inner = interior(out > 0, 3)
        assert inner.sum() > 0.5 * out.size
        rel = np.abs(out[inner] - truth[inner]) / truth[inner]
        assert rel.max() < 1e-4
        # near the edge of the covered area (footprints with constant depth) it stays close too
        edge = (out > 0) & ~inner
        assert (np.abs(out[edge] - truth[edge]) / truth[edge]).max() < 0.02

    def test_interpolation_is_perspective_correct(self):
        # A 12x9 depth grid drawn over 240x180 colour pixels (20x magnification), on a plane
        # inclined at 60 degrees: linear interpolation of z instead of 1/z would be off by ~1 %.
        rig = make_rig((12, 9), (240, 180), fd=10.0, fc=200.0, t=(-0.05, 0.0, 0.0), angles=(0.0, 0.0, 0.0))
        n = np.array([math.sin(math.radians(60)), 0.0, math.cos(math.radians(60))])
        o, dirs = depth_camera_rays(rig)
        depth = cast_plane(o, dirs, n, 1.5).reshape(rig.depth.shape).astype(np.float32)
        truth = cast_plane(np.zeros(3), rays_cv2(rig.color), n, 1.5).reshape(rig.color.shape)
        out = reproject_depth(depth, rig, max_depth_ratio=10.0)
        inner = interior(out > 0, 25)
        assert inner.sum() > 0.3 * out.size
        assert (np.abs(out[inner] - truth[inner]) / truth[inner]).max() < 1e-5


    def test_steep_plane_on_coarse_grid_is_not_torn(self):
        # A 64x48 depth camera (f = 45 px) sees a plane at 70 degrees incidence: neighbouring depth
        # pixels differ by ~6 %, more than a fixed 3 % ratio allows; the automatic ratio keeps it whole.
        rig = make_rig((64, 48), (256, 192), fd=45.0, fc=180.0, angles=(0.0, 0.0, 0.0))
        n = np.array([math.sin(math.radians(70)), 0.0, math.cos(math.radians(70))])
        o, dirs = depth_camera_rays(rig)
        depth = cast_plane(o, dirs, n, 1.0).reshape(rig.depth.shape).astype(np.float32)
        ok = (depth > 0) & (depth < 20)
        depth = np.where(ok, depth, 0).astype(np.float32)
        truth = cast_plane(np.zeros(3), rays_cv2(rig.color), n, 1.0).reshape(rig.color.shape)
        out = reproject_depth(depth, rig)
        inner = interior(out > 0, 6)
        assert inner.sum() > 0.4 * out.size
        assert (np.abs(out[inner] - truth[inner]) / truth[inner]).max() < 1e-4
        torn = reproject_depth(depth, rig, max_depth_ratio=0.03)
        assert (torn[inner] == 0).mean() > 0.05  # what a fixed 3 % would have done


class TestOcclusion:
    """A near box in front of a far wall, seen by two cameras 8 cm apart."""

    LO, HI = np.array([-0.12, -0.1, 0.8]), np.array([0.08, 0.12, 0.95])
    WALL = (np.array([0.0, 0.0, 1.0]), 2.5)

    def scene(self, rig):
        o, dirs = depth_camera_rays(rig)
        t_box = cast_box(o, dirs, self.LO, self.HI)
        t_wall = cast_plane(o, dirs, *self.WALL)
        depth = np.minimum(t_box, t_wall).reshape(rig.depth.shape).astype(np.float32)
        rays_c = rays_cv2(rig.color)
        box_c = np.isfinite(cast_box(np.zeros(3), rays_c, self.LO, self.HI)).reshape(rig.color.shape)
        # wall points seen by the colour camera that the depth camera cannot see (box in the way)
        wall_pts = rays_c * cast_plane(np.zeros(3), rays_c, *self.WALL)[:, None]
        to_depth_cam = o - wall_pts
        hidden = np.isfinite(cast_box(wall_pts, to_depth_cam, self.LO, self.HI))
        hidden = hidden.reshape(rig.color.shape) & ~box_c
        return depth, box_c, hidden

    def silhouette_distance(self, rig) -> np.ndarray:
        """Signed distance (colour pixels, > 0 inside) of each pixel centre to the box's silhouette."""
        corners = np.array([[x, y, z] for x in (self.LO[0], self.HI[0]) for y in (self.LO[1], self.HI[1])
                            for z in (self.LO[2], self.HI[2])])
        uv, _ = cv2.projectPoints(corners, np.zeros(3), np.zeros(3), rig.color.K, rig.color.dist_coeffs)
        hull = cv2.convexHull(uv.reshape(-1, 1, 2).astype(np.float32))
        H, W = rig.color.shape
        return np.array([[cv2.pointPolygonTest(hull, (float(x), float(y)), True) for x in range(W)]
                         for y in range(H)])

    @pytest.mark.parametrize("magnified", [False, True], ids=["1to1", "magnified"])
    @pytest.mark.parametrize("side", [-1.0, 1.0], ids=["depth-left", "depth-right"])
    def test_no_wall_on_box_and_disocclusion_stays_empty(self, magnified, side):
        # the depth camera is rolled by 8 degrees so the box edges cross its pixel grid at every phase
        if magnified:
            rig = make_rig((128, 106), (240, 198), fd=91.4, fc=265.2, t=(0.08 * side, 0.0, 0.0),
                           angles=(0.6, -0.3, 8.0))
        else:
            rig = make_rig(t=(0.08 * side, 0.0, 0.0), angles=(0.6, -0.3, 8.0))
        depth, box, hidden = self.scene(rig)
        out = reproject_depth(depth, rig)
        dist = self.silhouette_distance(rig)
        assert ((dist > 0.5) == box)[np.abs(dist) > 0.5].all()  # the hull is the ray-cast silhouette
        # A depth pixel measures its whole footprint, so the silhouette is known to within half a
        # depth pixel: m / 2 colour pixels (m = magnification), plus a little for the rotation.
        m = rig.color.fx / rig.depth.fx
        tol = 0.55 * m + 0.3
        box_in = dist > tol
        assert box_in.sum() > 200
        # every pixel inside the box silhouette holds box depth: no wall seen through the box
        assert (out[box_in] > 0).all()
        assert out[box_in].max() < self.HI[2] * 1.01
        # and the box never spills over the wall beyond that tolerance
        outside = dist < -tol
        assert (out[outside & (out > 0)] > 2.0).all()
        # the wall the depth camera could not see stays unknown (no bridging, no background copy)
        hid = interior(hidden, int(math.ceil(tol)))
        assert hid.sum() > 50
        assert (out[hid] == 0).all()

    def test_depth_step_is_not_bridged(self):
        rig = make_rig(t=(-0.05, 0.0, 0.0))
        depth = np.full(rig.depth.shape, 2.0, np.float32)
        depth[:, : rig.depth.width // 2] = 1.0
        out = reproject_depth(depth, rig)
        between = (out > 1.03 * 1.0) & (out < 2.0 / 1.03)
        assert not between.any()


class TestAgainstOpenCV:
    def test_smooth_scene_agrees_with_cv2_register_depth(self):
        # cv2.registerDepth ignores depth-camera distortion, so the depth camera has none here;
        # it does model the colour distortion.
        rig = make_rig(fd=145.0, fc=140.0, cdist=COLOR_DIST)
        vv, uu = np.mgrid[0 : rig.depth.height, 0 : rig.depth.width]
        depth = (2.0 + 0.03 * np.sin(uu / 40.0) * np.cos(vv / 30.0)).astype(np.float32)  # slope < 1 mm/px
        ours = reproject_depth(depth, rig)
        ref = cv2.registerDepth(rig.depth.K, rig.color.K, rig.color.dist_coeffs, np.asarray(rig.T_color_from_depth),
                                depth, (rig.color.width, rig.color.height))
        ref = np.nan_to_num(ref, nan=0.0)
        both = (ours > 0) & (ref > 0)
        assert both.mean() > 0.7
        assert np.abs(ours[both] - ref[both]).max() < 1e-3


class TestRegisterDepth:
    def test_identity_rig_copies_without_reprojection(self, monkeypatch):
        intr = Intrinsics(40, 30, 35.0, 35.0, 19.5, 14.5, (0.1, 0.0, 0.0, 0.0, 0.0))
        rig = Rig.registered(intr)
        assert needs_registration(rig) == (False, needs_registration(rig)[1])
        assert "already" in needs_registration(rig)[1]

        def boom(*args, **kwargs):
            raise AssertionError("reprojection kernel called for a registered rig")

        for name in ("project_and_code", "rasterise", "reproject_depth"):  # the two passes' kernels, and their caller
            monkeypatch.setattr(register_reproject, name, boom)
        depth = np.random.default_rng(0).uniform(0.5, 3.0, (30, 40)).astype(np.float32)
        depth[3, 4] = 0.0
        frame = RGBDFrame(np.zeros((30, 40, 3), np.uint8), depth, rig)
        out = register_depth(frame)
        np.testing.assert_array_equal(out, depth)
        assert out is not frame.depth_m and out.dtype == np.float32
        out[0, 0] = 99.0
        assert frame.depth_m[0, 0] != 99.0

    def test_needs_registration_reasons(self):
        rig = make_rig()
        needed, reason = needs_registration(rig)
        assert needed and "mm apart" in reason
        intr = Intrinsics(40, 30, 35.0, 35.0, 19.5, 14.5)
        other = Intrinsics(20, 15, 17.5, 17.5, 9.5, 7.0)
        needed, reason = needs_registration(Rig(intr, other))
        assert needed and "differs" in reason

    def test_frame_path_matches_array_path(self):
        rig = make_rig(ddist=DEPTH_DIST)
        depth = np.full(rig.depth.shape, 1.5, np.float32)
        frame = RGBDFrame(np.zeros((*rig.color.shape, 3), np.uint8), depth, rig)
        np.testing.assert_array_equal(register_depth(frame), reproject_depth(depth, rig))

    def test_unknown_depth_values(self):
        rig = make_rig()
        rng = np.random.default_rng(5)
        depth = rng.uniform(1.0, 1.01, rig.depth.shape).astype(np.float32)
        bad = rng.random(rig.depth.shape) < 0.1
        clean = np.where(bad, 0.0, depth).astype(np.float32)
        for fill in (np.nan, np.inf, -np.inf, -1.0):
            dirty = np.where(bad, fill, depth).astype(np.float32)
            np.testing.assert_array_equal(reproject_depth(dirty, rig), reproject_depth(clean, rig))
        assert not reproject_depth(np.zeros(rig.depth.shape), rig).any()

    def test_isolated_pixels_are_kept(self):
        for magnified in (False, True):
            rig = make_rig((128, 106), (480, 270), fd=91.4, fc=265.2) if magnified else make_rig()
            depth = np.zeros(rig.depth.shape, np.float32)
            depth[40, 50] = 1.7
            depth[60, 20] = 2.3
            out = reproject_depth(depth, rig)
            vals = np.unique(out[out > 0])
            np.testing.assert_allclose(np.sort(vals), [1.7, 2.3], atol=0.02)
            # each covers about its projected footprint (at least one pixel)
            m = rig.color.fx / rig.depth.fx
            for v in (1.7, 2.3):
                n = int((np.abs(out - v) < 0.02).sum())
                assert max(1, (math.ceil(m) - 1) ** 2) <= n <= (m + 1) ** 2

    def test_plans_do_not_change_the_result(self):
        import numba

        rig = make_rig((128, 106), (480, 270), fd=91.4, fc=265.2, ddist=DEPTH_DIST, cdist=COLOR_DIST)
        depth, _, _ = TestOcclusion().scene(rig)
        ref = reproject_depth(depth, rig)
        assert register_mod.plan_for(rig) == plan_register(106, 270)
        for threads in sorted({1, numba.config.NUMBA_NUM_THREADS}):
            for chunks, bands in ((1, 1), (3, 17), (17, 3), (500, 500)):
                plan = RegisterPlan(threads=threads, chunks=chunks, bands=bands)
                np.testing.assert_array_equal(reproject_depth(depth, rig, plan=plan), ref)
        frame = RGBDFrame(np.zeros((*rig.color.shape, 3), np.uint8), depth, rig)
        np.testing.assert_array_equal(register_depth(frame, plan=RegisterPlan(1, 2, 5)), ref)

    def test_small_quad_kernels_agree(self):
        # the 4x4 block kernel and the per-pixel tests evaluate the same triangles (float32 against
        # float64 edge functions): pixel centres on an edge may fall either way, depths agree
        rig = make_rig((128, 106), (480, 270), fd=91.4, fc=265.2, ddist=DEPTH_DIST, cdist=COLOR_DIST)
        depth, _, _ = TestOcclusion().scene(rig)
        block = reproject_depth(depth, rig)
        plain = reproject_depth(depth, rig, plan=dataclasses.replace(register_mod.plan_for(rig), block_kernel=False))
        both = (block > 0) & (plain > 0)
        assert both.sum() > 0.5 * block.size
        assert np.count_nonzero((block > 0) != (plain > 0)) < 1e-3 * block.size
        np.testing.assert_allclose(block[both], plain[both], rtol=1e-5)

    def test_bad_plan(self):
        rig = make_rig()
        depth = np.ones(rig.depth.shape, np.float32)
        with pytest.raises(InputError, match="plan must be a RegisterPlan"):
            reproject_depth(depth, rig, plan={"threads": 1})
        with pytest.raises(InputError, match="RegisterPlan.bands"):
            reproject_depth(depth, rig, plan=RegisterPlan(threads=1, chunks=1, bands=0))
        with pytest.raises(InputError, match="RegisterPlan.threads"):
            reproject_depth(depth, rig, plan=RegisterPlan(threads=10**6, chunks=1, bands=1))
        frame = RGBDFrame(np.zeros((*rig.color.shape, 3), np.uint8), depth, Rig.registered(rig.color))
        with pytest.raises(InputError, match="RegisterPlan.chunks"):  # checked even when nothing is re-projected
            register_depth(frame, plan=RegisterPlan(threads=1, chunks=-1, bands=1))

    def test_a_helper_that_never_runs_does_not_stall_the_call(self, monkeypatch):
        from pcdof.runtime.threads import fixed_threads, max_threads

        if max_threads() < 2:
            pytest.skip("needs two numba threads")
        with fixed_threads(2):  # whatever count a test before left this thread with
            self._helper_that_never_runs(monkeypatch)

    def _helper_that_never_runs(self, monkeypatch):
        import threading
        from concurrent.futures import ThreadPoolExecutor

        rig = make_rig((128, 106), (480, 270), fd=91.4, fc=265.2)
        depth, _, _ = TestOcclusion().scene(rig)
        ref = reproject_depth(depth, rig)
        release = threading.Event()
        released = []  # True: the call returned first and released the helper; False: the call waited for it
        busy = ThreadPoolExecutor(max_workers=1)
        try:
            busy.submit(lambda: released.append(release.wait(120)))  # the only helper thread is taken
            monkeypatch.setattr(register_tasks, "thread_pool", lambda: busy)
            out = reproject_depth(depth, rig)  # the caller does every task
            release.set()
            np.testing.assert_array_equal(out, ref)
        finally:
            release.set()
            busy.shutdown(wait=True)
        assert released == [True]

    def test_rig_work_is_done_once_per_calibration(self):
        rig = make_rig(ddist=DEPTH_DIST, cdist=COLOR_DIST)
        twin = Rig(rig.color, rig.depth, np.array(rig.T_color_from_depth))  # another object, same calibration
        consts = rig_constants(rig)
        assert rig_constants(twin) is consts
        assert not consts.rays.flags.writeable and consts.rays.shape == (3, *rig.depth.shape)
        other = make_rig(ddist=DEPTH_DIST, cdist=COLOR_DIST, t=(-0.04, 0.0, 0.0))
        assert rig_constants(other) is not consts

    def test_full_opencv_lens_model(self):
        # rational (k4..k6), thin prism (s1..s4) and tilted-sensor terms of the colour camera; each
        # group alone moves some of these points by 0.9 to 5 colour pixels
        cdist = (0.11, -0.21, 0.001, -0.0015, 0.05, 0.3, -0.2, 0.1, 0.03, -0.02, 0.025, 0.015, 0.05, -0.04)
        rig = make_rig(cdist=cdist, ddist=DEPTH_DIST)
        depth = np.zeros(rig.depth.shape, np.float32)
        picks = [(20, 30, 1.2), (60, 80, 2.1), (100, 140, 1.6), (15, 150, 2.8)]
        for i, j, z in picks:
            depth[i, j] = z
        out = reproject_depth(depth, rig)
        T = np.asarray(rig.T_color_from_depth)
        rays = rays_cv2(rig.depth).reshape(*rig.depth.shape, 3)
        for i, j, z in picks:
            p = T[:3, :3] @ (rays[i, j] * z) + T[:3, 3]
            uv, _ = cv2.projectPoints(p[None], np.zeros(3), np.zeros(3), rig.color.K, rig.color.dist_coeffs)
            u, v = uv.ravel()
            ys, xs = np.nonzero(np.abs(out - p[2]) < 1e-4 * p[2])
            assert len(xs) > 0, (i, j)
            # every pixel drawn lies within the footprint (half a depth pixel, 0.45 colour pixels here)
            # around the projection; a lens term left out would move it by 0.9 px or more
            half = 0.5 * rig.color.fx / rig.depth.fx * z / p[2] + 1e-3
            assert np.abs(xs - u).max() <= half and np.abs(ys - v).max() <= half, (i, j, xs, u, ys, v)

    def test_invalid_input(self):
        rig = make_rig()
        with pytest.raises(InputError, match=r"depth_m must be \(H, W\) = \(120, 160\)"):
            reproject_depth(np.ones((10, 10)), rig)
        with pytest.raises(InputError, match="rig must be a Rig"):
            reproject_depth(np.ones((120, 160)), "rig")
        with pytest.raises(InputError, match="max_depth_ratio"):
            reproject_depth(np.ones((120, 160)), rig, max_depth_ratio=0)
        with pytest.raises(InputError, match="frame must be an RGBDFrame"):
            register_depth(np.ones((120, 160)))
        with pytest.raises(InputError, match="numeric"):
            reproject_depth(np.full((120, 160), "x"), rig)


# ---------------------------------------------------------------------------------------------
# Real captured data (copied into data/real by the io module's tests setup)

REAL = {
    # name: (folder, colour, depth, calibration, registered?)
    "tum": ("tum_rgbd_open3d", "color.png", "depth.png", "calib.json", True),
    "nyu": ("nyu_v2_raw_open3d", "color.png", "depth.png", "calib.json", False),
    "adirondack-im1": ("middlebury2014_evalQ/Adirondack", "im1.png", "depth0.png", "calib.json", False),
    "adirondack-im0": ("middlebury2014_evalQ/Adirondack", "im0.png", "depth0.png", "calib_im0.json", True),
    "motorcycle-im1": ("middlebury2014_evalQ/Motorcycle", "im1.png", "depth0.png", "calib.json", False),
    "motorcycle-im0": ("middlebury2014_evalQ/Motorcycle", "im0.png", "depth0.png", "calib_im0.json", True),
}

needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"real RGB-D samples not found in {DATA}")


def load(name):
    from pcdof.io import load_frame

    folder, color, depth, calib, _ = REAL[name]
    base = DATA / folder
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_frame(base / color, base / depth, base / calib)


@needs_data
def test_every_real_calibration_is_covered():
    found = {str(p.relative_to(DATA)) for p in DATA.rglob("calib*.json")}
    covered = {f"{folder}/{calib}" for folder, _, _, calib, _ in REAL.values()}
    assert found == covered


@needs_data
@pytest.mark.parametrize("name", list(REAL))
def test_real_data_registers(name):
    frame = load(name)
    registered = REAL[name][4]
    assert needs_registration(frame.rig)[0] is not registered
    out = register_depth(frame)
    assert out.shape == frame.rig.color.shape and out.dtype == np.float32
    assert np.isfinite(out).all() and (out >= 0).all()
    if registered:
        np.testing.assert_array_equal(out, frame.depth_m)
        return
    valid_in = (frame.depth_m > 0).mean()
    coverage = (out > 0).mean()
    assert 0.75 * valid_in < coverage <= 1.0
    # the depth range is preserved (no values invented outside the measured range)
    known = frame.depth_m[frame.depth_m > 0]
    assert out[out > 0].min() >= 0.9 * known.min() and out.max() <= 1.1 * known.max()


@needs_data
def test_nyu_agrees_with_cv2_in_the_bulk():
    frame = load("nyu")
    rig = frame.rig
    ours = register_depth(frame)
    ref = np.nan_to_num(cv2.registerDepth(rig.depth.K, rig.color.K, rig.color.dist_coeffs,
                                          np.asarray(rig.T_color_from_depth), frame.depth_m,
                                          (rig.color.width, rig.color.height)), nan=0.0)
    both = (ours > 0) & (ref > 0)
    # cv2 ignores the depth camera's distortion, so only the bulk is expected to agree
    assert both.mean() > 0.6
    assert np.median(np.abs(ours[both] - ref[both])) < 0.005


@needs_data
@pytest.mark.parametrize("scene", ["Adirondack", "Motorcycle"])
def test_middlebury_registration_is_photometrically_consistent(scene):
    """Registered depth in cam1 maps each cam1 pixel to the cam0 pixel showing the same point."""
    frame = load(f"{scene.lower()}-im1")
    rig = frame.rig
    out = register_depth(frame)
    im0 = cv2.imread(str(DATA / "middlebury2014_evalQ" / scene / "im0.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    im1 = cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY).astype(np.float32)
    have = out > 0
    rays = rays_cv2(rig.color).reshape(*rig.color.shape, 3)
    P1 = rays[have] * out[have][:, None]
    T = np.asarray(rig.T_color_from_depth)
    P0 = (P1 - T[:3, 3]) @ T[:3, :3]  # into cam0 (the depth camera)
    uv, _ = cv2.projectPoints(P0, np.zeros(3), np.zeros(3), rig.depth.K, rig.depth.dist_coeffs)
    u, v = uv.reshape(-1, 2).T
    ok = (u >= 0) & (u <= im0.shape[1] - 1) & (v >= 0) & (v <= im0.shape[0] - 1)
    u0 = np.minimum(np.floor(u).astype(int), im0.shape[1] - 2)
    v0 = np.minimum(np.floor(v).astype(int), im0.shape[0] - 2)
    u0, v0 = np.clip(u0, 0, None), np.clip(v0, 0, None)
    fu, fv = u - u0, v - v0
    sampled = ((1 - fv) * ((1 - fu) * im0[v0, u0] + fu * im0[v0, u0 + 1])
               + fv * ((1 - fu) * im0[v0 + 1, u0] + fu * im0[v0 + 1, u0 + 1]))
    err = np.abs(sampled[ok] - im1[have][ok]).mean()
    baseline = np.abs(im0[have] - im1[have]).mean()  # no registration at all
    assert err < 12.0 and err < 0.4 * baseline


# ---------------------------------------------------------------------------------------------
# The peer comparison's metrics and runner (pcdof.bench.registration)


class TestRegistrationBench:
    def test_metrics_on_known_answers(self):
        from pcdof.bench.registration import BOXES_SCENE, bench_rig, measured_mask, render_depths, score

        rig = bench_rig((64, 53), (120, 68))
        clean, truth = render_depths(BOXES_SCENE, rig)
        measured = measured_mask(truth, clean, rig)
        # the colour camera sees wider than the depth camera: its border is not measured
        assert 0.5 < measured.mean() < 0.98 and not measured[:, 0].any()
        perfect = score(truth, truth, measured)
        assert perfect["coverage_pct"] == 100.0 and perfect["mae_mm"] == 0.0 and perfect["bleed_pct"] == 0.0
        behind = score(truth * 1.5, truth, measured)
        assert behind["bleed_pct"] == 100.0 and behind["fatten_pct"] == 0.0
        assert behind["mae_mm"] == pytest.approx(500 * truth[truth > 0].mean(), rel=1e-5)

    def test_quick_run_rows(self):
        from pcdof.bench.registration import METHODS, format_registration_table, run_registration_bench

        rows = run_registration_bench(sizes=[((64, 53), (240, 135))], quick=True, progress=False, synth_scenes=[],
                                      isolate=False)
        assert [r["method"] for r in rows] == list(METHODS)
        ours, peers = rows[0], rows[1:]
        assert ours["method"] == "pcdof" and ours["speedup_vs_fastest_peer"] > 0
        # a 3.75x magnification: point splats leave most of the image empty, the mesh does not
        assert ours["coverage_pct"] > 95 and all(p["coverage_pct"] < 60 for p in peers)
        assert ours["mae_mm"] < min(p["mae_mm"] for p in peers)
        table = format_registration_table(rows)
        assert table.count("\n| boxes") == len(rows) and "opencv" in table
