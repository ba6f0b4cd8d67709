"""pcdof.geometry: back-projection, projection with OpenCV distortion, transforms.

References: cv2.projectPoints / cv2.undistortPoints and closed-form pinhole geometry.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pcdof.camera import Intrinsics
from pcdof.errors import InputError
from pcdof.geometry import (
    depth_to_points,
    max_radius2,
    pixel_rays,
    project_points,
    transform_points,
    undistort_pixels,
)

# Distortion vectors of every OpenCV length, realistic magnitudes (the 5-vectors are the NYU
# Kinect v1 depth and colour calibrations).
DISTORTIONS = {
    "none": (),
    "4": (0.05, -0.1, 0.001, -0.002),
    "nyu-depth": (-0.0999, 0.3907, 0.0019, -0.0019, -0.5103),
    "nyu-color": (0.2080, -0.5861, 0.0007, 0.0010, 0.4986),
    "rational-8": (0.1, -0.05, 0.001, 0.002, 0.01, 0.05, -0.01, 0.002),
    "prism-12": (0.1, -0.05, 0.001, 0.002, 0.01, 0.05, -0.01, 0.002, 0.001, -0.002, 0.003, 0.0005),
    "tilt-14": (0.1, -0.05, 0.001, 0.002, 0.01, 0.05, -0.01, 0.002, 0.001, -0.002, 0.003, 0.0005, 0.01, -0.02),
}


def intr(dist=(), w=160, h=120, fx=150.0, fy=151.0, cx=81.3, cy=58.7) -> Intrinsics:
    return Intrinsics(w, h, fx, fy, cx, cy, dist)


def pixel_grid(i: Intrinsics) -> np.ndarray:
    vv, uu = np.mgrid[0 : i.height, 0 : i.width]
    return np.stack([uu.ravel(), vv.ravel()], axis=-1).astype(np.float64)


class TestProjectPoints:
    @pytest.mark.parametrize("name", list(DISTORTIONS))
    def test_agrees_with_cv2(self, name):
        i = intr(DISTORTIONS[name])
        rng = np.random.default_rng(1)
        pts = rng.uniform([-1.2, -1.0, 0.5], [1.2, 1.0, 4.0], size=(2000, 3))
        uv, valid = project_points(pts, i, return_mask=True)
        ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), i.K, i.dist_coeffs)
        r2 = (pts[:, 0] ** 2 + pts[:, 1] ** 2) / pts[:, 2] ** 2
        np.testing.assert_array_equal(valid, r2 <= max_radius2(i))  # refused only past the model's fold
        assert valid.mean() > 0.7
        np.testing.assert_allclose(uv[valid], ref.reshape(-1, 2)[valid], atol=1e-8, rtol=0)

    def test_points_behind_or_on_camera_plane_are_masked(self):
        i = intr(DISTORTIONS["nyu-color"])
        pts = np.array([[0.1, 0.1, 1.0], [0.1, 0.1, 0.0], [0.1, 0.1, -1.0], [0.0, 0.0, -1e-9], [np.nan, 0, 1],
                        [np.inf, 0, 1]])
        uv, valid = project_points(pts, i, return_mask=True)
        assert valid.tolist() == [True, False, False, False, False, False]
        assert np.isfinite(uv[0]).all() and np.isnan(uv[1:]).all()

    def test_no_fold_back_beyond_monotonic_radius(self):
        # k1 = -0.5: r * (1 - 0.5 r^2) peaks at r^2 = 2/3 and folds back; cv2 maps a point far
        # outside the field of view (r = 1.5) into the image, on the wrong side.
        i = intr((-0.5, 0.0, 0.0, 0.0, 0.0))
        assert max_radius2(i) == pytest.approx(2 / 3, rel=1e-3)
        far = np.array([[1.5, 0.0, 1.0]])
        ref, _ = cv2.projectPoints(far, np.zeros(3), np.zeros(3), i.K, i.dist_coeffs)
        assert 0 <= ref[0, 0, 0] < i.width  # the trap: OpenCV puts it inside the image
        uv, valid = project_points(far, i, return_mask=True)
        assert not valid[0] and np.isnan(uv).all()
        near = np.array([[0.7, 0.0, 1.0]])
        assert project_points(near, i, return_mask=True)[1][0]

    def test_pinhole_closed_form(self):
        i = intr()
        pts = np.array([[0.3, -0.2, 2.0], [0.0, 0.0, 1.0]])
        expect = np.array([[i.fx * 0.15 + i.cx, i.fy * -0.1 + i.cy], [i.cx, i.cy]])
        np.testing.assert_allclose(project_points(pts, i), expect, atol=1e-12)

    def test_invalid_input(self):
        with pytest.raises(InputError, match=r"points must be an \(N, 3\) array; got shape \(3,\)"):
            project_points(np.zeros(3), intr())
        with pytest.raises(InputError, match="intrinsics must be an Intrinsics"):
            project_points(np.zeros((1, 3)), "K")
        with pytest.raises(InputError, match="numeric"):
            project_points(np.array([["a", "b", "c"]]), intr())


class TestRoundTrip:
    @pytest.mark.parametrize("name", list(DISTORTIONS))
    def test_project_back_project_is_identity(self, name):
        i = intr(DISTORTIONS[name])
        rng = np.random.default_rng(2)
        depth = rng.uniform(0.5, 5.0, size=i.shape)
        pts, idx = depth_to_points(depth, i, return_index=True)
        assert len(idx) == i.width * i.height  # every pixel of these mild models has an inverse
        uv = project_points(pts, i)
        err = np.abs(uv - pixel_grid(i)[idx]).max()
        assert err < 1e-6
        np.testing.assert_allclose(pts[:, 2], depth.ravel()[idx], rtol=1e-6)

    @settings(max_examples=25, deadline=None)
    @given(k1=st.floats(-0.3, 0.3), k2=st.floats(-0.3, 0.3), p1=st.floats(-0.01, 0.01), p2=st.floats(-0.01, 0.01),
           k3=st.floats(-0.2, 0.2), fx=st.floats(50, 500), cx=st.floats(10, 60))
    def test_round_trip_property(self, k1, k2, p1, p2, k3, fx, cx):
        i = Intrinsics(64, 48, fx, fx * 1.01, cx, 23.5, (k1, k2, p1, p2, k3))
        uv = pixel_grid(i)
        xy = undistort_pixels(uv, i)
        ok = np.isfinite(xy[:, 0])
        pts = np.column_stack([xy[ok] * 2.0, np.full(ok.sum(), 2.0)])
        back, valid = project_points(pts, i, return_mask=True)
        assert valid.all()
        assert np.abs(back - uv[ok]).max() < 1e-6
        # pixels without an inverse exist only when the model folds back
        if not ok.all():
            assert np.isfinite(max_radius2(i))

    def test_pixel_rays_match_cv2_undistort(self):
        i = intr(DISTORTIONS["nyu-depth"])
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)
        ref = cv2.undistortPoints(pixel_grid(i).reshape(-1, 1, 2), i.K, i.dist_coeffs, criteria=criteria)
        np.testing.assert_allclose(pixel_rays(i).reshape(-1, 2), ref.reshape(-1, 2), atol=1e-8)


class TestPixelRays:
    def test_shape_cache_readonly(self):
        i = intr(DISTORTIONS["4"])
        rays = pixel_rays(i)
        assert rays.shape == (i.height, i.width, 2) and rays.dtype == np.float64
        assert pixel_rays(Intrinsics(**i.to_dict())) is rays  # cached per (equal) intrinsics
        assert not rays.flags.writeable

    def test_pinhole_closed_form(self):
        i = intr()
        rays = pixel_rays(i)
        assert rays[0, 0, 0] == pytest.approx(-i.cx / i.fx) and rays[0, 0, 1] == pytest.approx(-i.cy / i.fy)
        assert rays[7, 11, 0] == pytest.approx((11 - i.cx) / i.fx)


class TestDepthToPoints:
    def test_closed_form_and_unknowns(self):
        i = intr(w=4, h=3, fx=2.0, fy=4.0, cx=1.5, cy=1.0)
        depth = np.full((3, 4), 2.0, dtype=np.float32)
        depth[0, 0] = 0.0
        depth[0, 1] = np.nan
        depth[1, 1] = np.inf
        depth[2, 3] = -1.0
        pts, idx = depth_to_points(depth, i, return_index=True)
        assert idx.tolist() == [2, 3, 4, 6, 7, 8, 9, 10]
        v, u = np.divmod(idx, 4)
        np.testing.assert_allclose(pts[:, 0], (u - 1.5) / 2.0 * 2.0)
        np.testing.assert_allclose(pts[:, 1], (v - 1.0) / 4.0 * 2.0)
        np.testing.assert_allclose(pts[:, 2], 2.0)
        assert depth_to_points(np.zeros((3, 4)), i).shape == (0, 3)

    def test_shape_checked(self):
        with pytest.raises(InputError, match=r"depth_m must be \(H, W\) = \(3, 4\); got \(4, 3\)"):
            depth_to_points(np.ones((4, 3)), intr(w=4, h=3))


class TestTransformPoints:
    def test_matches_homogeneous_product(self):
        rng = np.random.default_rng(3)
        a = 0.3
        T = np.eye(4)
        T[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        T[:3, 3] = [0.1, -0.2, 0.05]
        p = rng.normal(size=(50, 3))
        expect = (T @ np.column_stack([p, np.ones(50)]).T).T[:, :3]
        np.testing.assert_allclose(transform_points(T, p), expect, atol=1e-12)
        # inverse transform returns the points
        np.testing.assert_allclose(transform_points(np.linalg.inv(T), transform_points(T, p)), p, atol=1e-12)

    def test_bad_shapes(self):
        with pytest.raises(InputError, match=r"T must be a \(4, 4\) matrix; got shape \(3, 3\)"):
            transform_points(np.eye(3), np.zeros((1, 3)))
        with pytest.raises(InputError, match=r"points must be an \(N, 3\)"):
            transform_points(np.eye(4), np.zeros((2, 2)))
