"""pcdof.stages.register's row kernel (quads up to 16 colour pixels wide) against closed forms and its per-triangle path.

The row kernel evaluates float32 edge functions relative to each quad's own origin; these tests
check that a surface tiled by quads whose corners fall on (or within float rounding of) pixel
centres is drawn without cracks and with the exact interpolated depth, for every quad width
the kernel takes and beyond, and that it agrees with the float64 per-triangle path on random
frames with holes, steps and lens distortion.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import pcdof.stages.register as register_mod
from pcdof.camera import Intrinsics, Rig
from pcdof.stages.register import reproject_depth, warmup


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warmup()


def _scaled_rig(scale: int, *, w=24, h=20) -> Rig:
    """Coinciding cameras, the colour grid *scale* times finer: depth pixel (i, j) lands on colour (s i, s j)."""
    depth = Intrinsics(w, h, 20.0, 20.0, 10.0, 8.0)
    color = Intrinsics(w * scale, h * scale, 20.0 * scale, 20.0 * scale, 10.0 * scale, 8.0 * scale)
    return Rig(color, depth, np.eye(4))


def _plan(rig, rows: bool):
    return dataclasses.replace(register_mod.plan_for(rig), block_kernel=rows)


@pytest.mark.parametrize("rows", [True, False], ids=["row-kernel", "per-triangle"])
@pytest.mark.parametrize("scale", [2, 3, 5, 8, 15, 16, 23])
def test_plane_on_pixel_centres_has_no_cracks(scale, rows):
    # a 3-D plane: 1/z affine in the image, so interpolating 1/z is exact; every quad corner lies within
    # float32 rounding of a colour pixel centre, so every centre inside the mesh sits on an edge or a corner
    rig = _scaled_rig(scale)
    h, w = rig.depth.shape
    ii, jj = np.mgrid[0:h, 0:w]
    depth = (1.0 / (0.5 + 0.004 * jj - 0.003 * ii)).astype(np.float32)
    out = reproject_depth(depth, rig, plan=_plan(rig, rows))
    # the centres inside the mesh; those on its outer boundary may fall either way (the edge pixels'
    # footprints cover them, up to rounding at the footprints' own edges)
    yy, xx = np.mgrid[1:scale * (h - 1), 1:scale * (w - 1)]
    expected = 1.0 / (0.5 + 0.004 * xx / scale - 0.003 * yy / scale)
    inside = out[1:scale * (h - 1), 1:scale * (w - 1)]
    assert np.count_nonzero(inside == 0) == 0, np.argwhere(inside == 0)[:5]
    np.testing.assert_allclose(inside, expected, rtol=2e-6)


@pytest.mark.parametrize("rows", [True, False], ids=["row-kernel", "per-triangle"])
@pytest.mark.parametrize("scale", [3, 7, 16])
def test_one_triangle_quads_stop_at_their_edges(scale, rows):
    # a depth step along a diagonal of the grid: the quads on it keep their one triangle on the near
    # side, drawn exactly up to its edges; the gap across the step (a discontinuity) is not bridged
    rig = _scaled_rig(scale)
    h, w = rig.depth.shape
    ii, jj = np.mgrid[0:h, 0:w]
    depth = np.where(jj >= ii, 1.0, 2.0).astype(np.float32)
    out = reproject_depth(depth, rig, plan=_plan(rig, rows))
    yy, xx = np.mgrid[0:scale * (h - 1) + 1, 0:scale * (w - 1) + 1]
    inside = out[:yy.shape[0], :xx.shape[1]]
    tol = 1e-3 * scale  # corners lie within float32 rounding of the pixel centres
    np.testing.assert_array_equal(inside[xx >= yy - tol], 1.0)  # the kept triangles reach the diagonal
    np.testing.assert_array_equal(inside[xx <= yy - scale - tol], 2.0)
    gap = (xx < yy - tol) & (xx > yy - scale + tol)  # across the step: empty, or an edge pixel's footprint
    assert np.all(np.isin(inside[gap], (0.0, 1.0, 2.0))) and np.count_nonzero(inside[gap] == 0) > 0


def _random_rig(rng, scale: float, distorted: bool) -> Rig:
    dw, dh = 40, 32
    cw, ch = int(math.ceil(dw * scale)) + 4, int(math.ceil(dh * scale)) + 4
    ddist = (-0.0999, 0.3907, 0.0019, -0.0019, -0.5103) if distorted else ()
    cdist = (0.2080, -0.5861, 0.0007, 0.0010, 0.4986) if distorted else ()
    fd = 36.0
    depth = Intrinsics(dw, dh, fd, fd * 1.002, dw / 2 + rng.uniform(-1, 1), dh / 2 + rng.uniform(-1, 1), ddist)
    color = Intrinsics(cw, ch, fd * scale, fd * scale * 0.998, cw / 2 + rng.uniform(-1, 1),
                       ch / 2 + rng.uniform(-1, 1), cdist)
    T = np.eye(4)
    angle = rng.normal(0, 0.01)
    T[:2, :2] = [[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]]
    T[:3, 3] = (rng.uniform(-0.05, -0.01), rng.uniform(-0.005, 0.005), 0.0)
    return Rig(color, depth, T)


def _random_depth(shape, rng) -> np.ndarray:
    h, w = shape
    ii, jj = np.mgrid[0:h, 0:w]
    d = (rng.uniform(1.0, 3.0) + rng.uniform(-0.02, 0.02) * jj + rng.uniform(-0.02, 0.02) * ii).astype(np.float32)
    y0, x0 = rng.integers(0, h // 2), rng.integers(0, w // 2)
    d[y0:y0 + h // 3, x0:x0 + w // 3] = rng.uniform(0.5, 0.8)  # a step: one-triangle quads on its border
    d[rng.random((h, w)) < 0.04] = 0.0
    d[rng.random((h, w)) < 0.01] = np.nan
    return d


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([0.6, 1.0, 2.3, 4.5, 9.0, 14.0, 21.0]),
       distorted=st.booleans())
def test_row_kernel_matches_per_triangle_path(seed, scale, distorted):
    """The float32 row kernel and the float64 per-triangle path draw the same triangles: pixel centres
    within rounding of an edge may fall either way (at most 0.2 % of the covered pixels), depths agree."""
    rng = np.random.default_rng(seed)
    rig = _random_rig(rng, scale, distorted)
    depth = _random_depth(rig.depth.shape, rng)
    rows = reproject_depth(depth, rig, plan=_plan(rig, True))
    plain = reproject_depth(depth, rig, plan=_plan(rig, False))
    covered = np.count_nonzero(plain)
    assert covered > 0.3 * plain.size
    assert np.count_nonzero((rows > 0) != (plain > 0)) <= max(2, 2e-3 * covered)
    both = (rows > 0) & (plain > 0)
    close = np.isclose(rows[both], plain[both], rtol=1e-5, atol=0)
    # a centre on the edge between two surfaces may take either one
    assert np.count_nonzero(~close) <= max(2, 2e-3 * covered)
