"""Constants the registration's kernels share: the largest primitive drawn, the compiler's fast-math flags
and the quad split codes."""

from __future__ import annotations

#: Triangles or footprints whose bounding box is larger than this many pixels per side are dropped
#: (a guard against degenerate projections near the colour camera's plane z = 0).
MAX_PRIMITIVE_PX = 512

# Fast-math without "nnan"/"ninf": NaN and inf tests (unknown depth, rays without inverse) stay exact.
# The kernels use error_model="numpy": a division by zero gives inf or NaN instead of raising, so
# divisions need no zero test (the row projection evaluates the lens model for every pixel and
# drops the ones that fail, and every division the drawing uses is guarded).
FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

# Quad split codes: bit 0 = triangle (a, b, d), bit 1 = (a, d, c) [diagonal a-d];
# bit 2 = (a, b, c), bit 3 = (b, d, c) [diagonal b-c]; a = (i, j), b = (i, j+1), c = (i+1, j), d = (i+1, j+1).
# Bit 4 is set when both triangles of the split are kept (the quad is whole).
WHOLE = 0b10000
