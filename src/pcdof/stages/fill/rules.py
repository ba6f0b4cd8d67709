"""What the fill's kernels share: the defaults, the spatial constants (scaled to the image by
:func:`kernel_rules`), the 16 sweep directions, the codes of the index and of the kinds of hole, and the named
tuples the combine kernel reads."""

from __future__ import annotations

from collections import namedtuple

import numpy as np

#: Default relative depth gap that separates two surfaces among a hole pixel's candidates.
DEFAULT_EDGE_RATIO = 0.04
#: Default colour range sigma of the joint-bilateral weight (colour scaled to [0, 1]).
DEFAULT_SIGMA_COLOR = 0.04
#: Default factor by which a nearer surface's colour support must exceed the farthest one's.
DEFAULT_BACKGROUND_BIAS = 6.0
#: Default radius (pixels) of cv2.inpaint's neighbourhood for ``method="telea"``.
DEFAULT_TELEA_RADIUS_PX = 5.0
#: Rules for holes outside the depth camera's view (:mod:`pcdof.stages.fill`): "candidates" (the default) fills
#: them from the 16 directional candidates as other holes, without the preference for the farthest surface;
#: "extend" continues the plane of the surface that reaches the border along the row or column; "hold" holds
#: its depth constant (the rule of the releases before the benchmark of real rigs, pcdof.bench.fill_rigs).
BORDER_RULES = ("candidates", "extend", "hold")
DEFAULT_BORDER = "candidates"
#: What each border rule assumes, one line (the fill stage's trace and docs/fill.md say it).
BORDER_ASSUMPTIONS = {
    "candidates": "outside the depth view the surfaces at the border continue along their planes and colour "
                  "chooses among them without preferring the farthest (no disocclusion lies there); a surface "
                  "that runs nearer than all measured depth goes at most 10 % nearer, one that runs farther holds",
    "extend": "outside the depth view the surface at the border continues along its plane on the row or column "
              "(64 px at 640 across), then holds",
    "hold": "outside the depth view the surface at the border holds its depth along the row or column",
}

# The spatial constants below hold for images REFERENCE_SIZE_PX across (longest side) and
# scale with the image (the extrapolation cap only grows): they were tuned on the synthetic
# scenes of pcdof.synth at 640x480 and checked at 1920x1080.
REFERENCE_SIZE_PX = 640.0
# A "step" is max(1, round(size / REFERENCE_SIZE_PX)) pixels.
# Half size (in steps) of the window of the plane fit around each candidate.
FIT_RADIUS_STEPS = 5
# A candidate is extrapolated along its plane by at most this distance (pixels).
EXTRAPOLATE_PX = 64.0
# Outside the view ("extend"), the surface at the border continues along its plane for at most this distance
# (pixels), then holds; chosen on the tuning seeds of pcdof.bench.fill_rigs.
BORDER_EXTEND_PX = 64.0
# ... and its holes farther than MEDIAN_MIN_R_STEPS from the inside pixel get the median of step 5.
BORDER_MEDIAN = True
# Outside the view ("candidates"), the factor by which a nearer surface's colour support must exceed the
# farthest one's (inside, background_bias): no disocclusion lies there to prefer the background for. Chosen
# on the tuning seeds of pcdof.bench.fill_rigs: the lowest mean error with no scene type more than 2 mm
# worse than release 6787386 at outside-view holes (1: 179 mm, 2: 177.5, 4: 178.6, 6: 180.4).
BORDER_BIAS = 4.0
# Outside the view ("candidates"), a surface whose every candidate runs past the measured depth range (its planes,
# extrapolated to the hole, leave [min known, max known]) is not stopped at the range's end, which would give
# one value over the whole area: nearer than the nearest measured depth it continues along its planes, down to
# this factor nearer; farther than the farthest, each candidate holds its own measured depth. Chosen on the
# tuning seeds of pcdof.bench.fill_rigs (0-139): mean outside-view error 187.9 mm stopped at the range's end,
# 187.3 held on both sides, 187.3 with 1.1 (render 42.52, 42.43, 42.60 dB), 187.4 with 1.25 or 2.
BORDER_NEARER = 1.1
# Surface support weight 1 / (r + SUPPORT_PX): near candidates count more, far ones still count.
SUPPORT_PX = 20.0
# Colour samples per candidate, walked one step apart from it into the known region along its ray.
COLOR_SAMPLES = 11
# Holes farther than this many steps from their nearest candidate get a 5 x 5 median (taps one
# step apart), this many times: it removes the thin streaks deep inside large holes and leaves
# the pixels next to known depth (and so the depth edges there) as they are.
MEDIAN_MIN_R_STEPS = 3.0
MEDIAN_ITERATIONS = 2

#: Sweep directions (dx, dy) and the Bresenham half step checked between two knight steps.
DIRS = np.array([
    (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1),
    (2, 1), (1, 2), (-1, 2), (-2, 1), (-2, -1), (-1, -2), (1, -2), (2, -1),
], dtype=np.int64)
HALF = np.array([
    (0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0), (0, 0),
    (1, 0), (0, 1), (0, 1), (-1, 0), (-1, 0), (0, -1), (0, -1), (1, 0),
], dtype=np.int64)


#: What :func:`~pcdof.stages.fill.index.index_depth`'s code map holds at a hole, and at a known pixel with no
#: hole among its 8 neighbours (at a boundary pixel: its number, >= 0).
HOLE, INSIDE = -2, -1

# What the combine kernel reads: the holes and their candidates, the boundary pixels and their
# planes, and the rules (scalars in kernel units). Named tuples, so a kernel takes a few named
# arguments instead of a long positional list.
Holes = namedtuple("Holes", "y x cand")
Boundary = namedtuple("Boundary", "y x plane")
Rules = namedtuple("Rules", "use_color inv_two_sigma2 edge_ratio bias extrapolate_px support_px "
                             "n_samples step inv_lo inv_hi zmin zmax border border_px border_median border_bias "
                             "border_inv_hi border_zmin")
#: The border rules' codes in Rules.border (the order of BORDER_RULES).
CANDIDATES, EXTEND, HOLD = 0, 1, 2

#: Kinds of hole, as the combine kernel classifies them: inside or between surfaces, outside the
#: depth camera's view, and with nothing to take a depth from (filled afterwards).
SURFACE, BORDER, LOST = 0, 1, 2


def kernel_rules(shape, *, use_color, unit, edge_ratio, sigma_color, background_bias, zmin, zmax,
                 border=DEFAULT_BORDER) -> Rules:
    """The kernel's scalars: the spatial constants scaled to an image of *shape*, colour in kernel units."""
    scale = max(shape) / REFERENCE_SIZE_PX
    return Rules(
        use_color=bool(use_color), inv_two_sigma2=unit * unit / (2.0 * sigma_color * sigma_color),
        edge_ratio=float(edge_ratio), bias=float(background_bias), extrapolate_px=EXTRAPOLATE_PX * max(scale, 1.0),
        support_px=SUPPORT_PX * scale,
        n_samples=COLOR_SAMPLES, step=max(1, int(round(scale))), inv_lo=1.0 / zmax, inv_hi=1.0 / zmin,
        zmin=zmin, zmax=zmax, border=BORDER_RULES.index(border), border_px=BORDER_EXTEND_PX * max(scale, 1.0),
        border_median=bool(BORDER_MEDIAN and border == "extend"), border_bias=float(BORDER_BIAS),
        border_inv_hi=BORDER_NEARER / float(zmin), border_zmin=float(zmin) / BORDER_NEARER,
    )
