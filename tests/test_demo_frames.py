"""The bundled real frames as `pcdof demo` renders them: the TUM chair's blurred edge and the NYU frame's border.

Each test states a property a viewer checks by eye, measured on the demo's own subject, focus and lens.
Those that fail today are marked ``xfail(strict=True)`` with the measured cause, so the mark has to go
when the cause is fixed.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from pcdof import io, pipeline
from pcdof.cli.demo import (BACKGROUND_BLUR_PX, BACKGROUND_BLUR_WIDTH_PX, DATA, FRAMES, choose_lens,
                            pick_subject)
from pcdof.focus import depth_at
from pcdof.lens import ThinLens

#: the TUM chair back's top edge: columns, the rows searched for it, and the colour luminance below which
#: a pixel is the (dark yellow) chair rather than the (white) desk behind it
TUM_EDGE_COLUMNS = (450, 526)
TUM_EDGE_SEARCH_ROWS = (220, 262)
TUM_CHAIR_LUMA = 140.0
#: rows in a run below :data:`TUM_CHAIR_LUMA` that make the chair: a pen lying on the desk just above the chair
#: back (columns 495-498, rows 227-231) is as dark for two or three rows, and the rows checked below it are desk
TUM_CHAIR_ROWS = 4
#: rows of the render below the colour edge that are checked: there the blurred chair covers the desk partly
TUM_EDGE_ROWS = 6
#: a speckle: brighter than the median of the 9 pixels around it along the edge by more than this (8-bit levels)
SPECKLE_LEVELS = 12.0
SPECKLE_WINDOW = 9


def _demo(name: str):
    """(frame, registered, filled, lens, render) as `pcdof demo` makes them for frame *name*."""
    folder, *files = FRAMES[name]
    frame = io.load_frame(*(os.path.join(DATA, folder, f) for f in files))
    registered, filled, _ = pipeline.prepare_depth(frame, ThinLens(focal_length_mm=50.0, f_number=2.0,
                                                                   focus_distance_m=1.0))
    subject = pick_subject(filled)
    focus_m = depth_at(registered, filled, subject.x, subject.y)
    target = BACKGROUND_BLUR_PX * frame.rig.color.width / BACKGROUND_BLUR_WIDTH_PX
    lens, _, _ = choose_lens(filled, frame.rig.color.fx, focus_m, target_px=target)
    image, _ = pipeline.render_from_depth(frame.color, filled, lens, frame.rig.color.fx,
                                          max_range_m=frame.rig.max_range_m)
    return frame, registered, filled, lens, image


def edge_speckles(color: np.ndarray, image: np.ndarray) -> int:
    """Speckles along the TUM chair back's top edge in *image* (the render of *color*, both (H, W, 3) uint8).

    Per column of :data:`TUM_EDGE_COLUMNS`, the edge is the first row of :data:`TUM_EDGE_SEARCH_ROWS` that starts
    a run of :data:`TUM_CHAIR_ROWS` rows whose colour luminance (mean of R, G, B) is below :data:`TUM_CHAIR_LUMA`. On each of the :data:`TUM_EDGE_ROWS`
    rows from the edge down, the render's luminance is followed along the edge; a pixel more than
    :data:`SPECKLE_LEVELS` above the median of the :data:`SPECKLE_WINDOW` pixels centred on it is a speckle.
    The edge is nearly straight and the chair is blurred by about 17 px, so a faithful render varies slowly
    along it.
    """
    luma_in = color.astype(np.float64).mean(-1)
    luma_out = image.astype(np.float64).mean(-1)
    xs = np.arange(*TUM_EDGE_COLUMNS)
    top, bottom = TUM_EDGE_SEARCH_ROWS
    dark = luma_in[top:bottom + TUM_CHAIR_ROWS - 1] < TUM_CHAIR_LUMA
    chair = np.logical_and.reduce([dark[k:k + bottom - top] for k in range(TUM_CHAIR_ROWS)])
    edge = np.array([top + int(np.argmax(chair[:, x])) for x in xs])
    profile = np.stack([luma_out[edge + k, xs] for k in range(TUM_EDGE_ROWS)])
    half = SPECKLE_WINDOW // 2
    padded = np.pad(profile, ((0, 0), (half, half)), mode="edge")
    median = np.median(np.lib.stride_tricks.sliding_window_view(padded, SPECKLE_WINDOW, axis=1), axis=-1)
    return int(np.count_nonzero(profile - median > SPECKLE_LEVELS))


def largest_constant_patch(filled: np.ndarray, registered: np.ndarray) -> int:
    """Pixels of the largest 4-connected patch of filled holes (registered == 0) whose depth equals each
    neighbour's exactly along both axes: what holding one value over a block (a rectangle, a triangle) leaves."""
    import cv2

    z = filled.astype(np.float64)
    along_x = np.zeros(z.shape, bool)
    along_y = np.zeros(z.shape, bool)
    same_x = z[:, 1:] == z[:, :-1]
    same_y = z[1:] == z[:-1]
    along_x[:, 1:] |= same_x
    along_x[:, :-1] |= same_x
    along_y[1:] |= same_y
    along_y[:-1] |= same_y
    flat = along_x & along_y & (registered == 0)
    n, _, stats, _ = cv2.connectedComponentsWithStats(flat.astype(np.uint8), connectivity=4)
    return int(stats[1:, cv2.CC_STAT_AREA].max()) if n > 1 else 0


@pytest.fixture(scope="module")
def tum():
    return _demo("tum")


@pytest.fixture(scope="module")
def nyu():
    return _demo("nyu")


def test_speckle_measure_sees_one_sharp_pixel_on_the_edge(tum):
    frame = tum[0]
    flat = np.full(frame.color.shape, 100, np.uint8)  # what a uniformly blurred chair would give
    assert edge_speckles(frame.color, flat) == 0
    luma = frame.color.astype(np.float64).mean(-1)
    x, top = 490, TUM_EDGE_SEARCH_ROWS[0]
    y = top + int(np.argmax(luma[top:TUM_EDGE_SEARCH_ROWS[1], x] < TUM_CHAIR_LUMA)) + 2
    flat[y, x] = 100 + 2 * SPECKLE_LEVELS
    assert edge_speckles(frame.color, flat) == 1


@pytest.mark.xfail(strict=True, reason="8 speckles, at the columns where the chair's top edge steps by a row "
                                       "(518-520, 504): the desk continued behind the blurred chair copies the "
                                       "desk's edge pixels, which show the chair in part (mixed pixels), as pale "
                                       "triangles there. Joining such pixels to the nearer surface removes every "
                                       "speckle but loses 0.08 dB on the wide benchmark's report seeds (76 of 120 "
                                       "cases worse); giving them their surface's colour, 0.07 dB on the tuning "
                                       "seeds. Continuing the desk from one pixel further in where its edge pixel's "
                                       "colour lies between the chair's and the desk's also removes every speckle, "
                                       "but loses 0.02-0.04 dB on the tuning seeds (0.18 dB from one pixel further in "
                                       "everywhere): the ray-traced scenes' edge pixels are mostly the surface's own. "
                                       "The chair's first rows no longer carry the desk's depth (measured "
                                       "pixels moved onto the colour edge before the fill: 7 speckles before that, "
                                       "22 before the slanted desk was continued as one surface)")
def test_tum_chair_edge_has_no_speckles(tum):
    frame, _, _, _, image = tum
    assert edge_speckles(frame.color, image) == 0


def test_nyu_constant_patch_measure_sees_a_block():
    z = np.linspace(1.0, 2.0, 64 * 48, dtype=np.float32).reshape(48, 64)
    holes = np.zeros(z.shape, np.float32)
    assert largest_constant_patch(z, holes) == 0
    z[10:40, :12] = 3.0  # a rectangle along the left edge
    z[:8, 56:][np.add.outer(np.arange(8), -np.arange(8)) >= 0] = 2.5  # a triangle in a top corner
    assert largest_constant_patch(z, holes) == 30 * 12


def test_nyu_border_has_no_constant_block(nyu):
    _, registered, filled, _, _ = nyu
    assert largest_constant_patch(filled, registered) <= 100


@pytest.mark.xfail(strict=True, reason="no depth pixel measures the chair: the part inside the depth camera's view "
                                       "is a hole (too near for the sensor) and the rest is outside it, so the fill "
                                       "gives it the floor's depth, near the focus")
def test_nyu_near_chair_is_blurred_like_the_near_pole(nyu):
    frame, registered, filled, lens, _ = nyu
    coc = lens.coc_px(filled, frame.rig.color.fx)
    w = frame.rig.color.width
    pole = (registered > 0) & (registered < 1.7)
    pole[:, w // 3:] = False  # the black pole at the left, measured at about 1.5 m
    chair = np.zeros(pole.shape, bool)
    chair[360:460, w - 28:w - 4] = True  # well inside the wooden chair cut by the right edge
    assert pole.sum() > 1000
    assert np.median(coc[chair]) >= 0.5 * np.median(coc[pole])
