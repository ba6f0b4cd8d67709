"""Tile classification of a circle-of-confusion map: where the renderer has work to do.

The image is cut into square tiles of :data:`TILE_PX` pixels and each tile gets the range of its
signed circle of confusion (CoC, pixels, negative in front of the focus plane). From those
ranges alone (one pass over the map, then work on a grid 256 times smaller) the renderer learns:

* **copy** tiles: every pixel is in focus (|c| below the sharp limit) and no blurred pixel in
  front of the focus plane can spread onto the tile. Their output is their input, bit for bit;
  the renderer neither blurs nor composites them.
* **uniform** tiles: the tile and every pixel whose blur can reach it lie in one blur layer with
  nearly the same CoC (spread at most :data:`UNIFORM_SPREAD` of its size). There the layered
  scatter is a convolution with one fixed aperture kernel, which the renderer computes as such
  (:func:`pcdof.stages.render.render_layers_linear`).
* all other tiles are **mixed**: the exact per-pixel scatter runs there.

This is the tile classification of real-time depth-of-field renderers (min/max CoC per tile,
in-focus tiles skipped, cheap paths for tiles of constant blur), kept exact where it matters:
a copy tile is exact by construction and a uniform tile differs from the scatter only by the
spread of its CoC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from ...errors import InputError
from ...plans import TILE_PX  # noqa: F401  (the default tile side, pixels; re-exported)
from ...runtime.kernels import read_only
#: Largest relative CoC spread (max - min over mean) of a uniform tile and everything that reaches it.
UNIFORM_SPREAD = 0.1


@njit(cache=True, fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
def tile_ranges(coc, tile, sharp):
    """Per tile: min and max signed CoC, largest blur radius of its front pixels (c <= -sharp; else 0).

    NaN counts as 0 (in focus). Each tile's row segments are reduced into local accumulators.
    """
    h, w = coc.shape
    th, tw = (h + tile - 1) // tile, (w + tile - 1) // tile
    lo = np.empty((th, tw), np.float32)
    hi = np.empty((th, tw), np.float32)
    front_r = np.empty((th, tw), np.float32)
    for ty in range(th):
        for tx in range(tw):
            a = np.float32(np.inf)
            b = np.float32(-np.inf)
            f = np.float32(0.0)  # most negative c of the tile's front pixels
            for y in range(ty * tile, min(h, (ty + 1) * tile)):
                for x in range(tx * tile, min(w, (tx + 1) * tile)):
                    c = coc[y, x]
                    c = c if c == c else np.float32(0.0)
                    a = min(a, c)
                    b = max(b, c)
                    f = min(f, c)
            lo[ty, tx] = a
            hi[ty, tx] = b
            front_r[ty, tx] = -0.5 * f if f <= -sharp else 0.0
    return lo, hi, front_r


@njit(cache=True)
def _reached_from_front(front_r, tile):
    """Tiles onto which some front tile's blur can spread: within 2 r + 2 pixels of it.

    The margin covers the footprint radius r, the anti-aliased edge and the spread that the
    renderer's reduced-resolution layers add (at most r).
    """
    th, tw = front_r.shape
    reached = np.zeros((th, tw), np.bool_)
    for ty in range(th):
        for tx in range(tw):
            r = front_r[ty, tx]
            if r <= 0.0:
                continue
            k = int(math.ceil((2.0 * r + 2.0) / tile))
            for yy in range(max(0, ty - k), min(th, ty + k + 1)):
                for xx in range(max(0, tx - k), min(tw, tx + k + 1)):
                    reached[yy, xx] = True
    return reached


def window_range(lo, hi, k):
    """Min of *lo* and max of *hi* (th, tw) over the (2k+1)^2 tile window around each tile (cut at the border):
    OpenCV's erosion and dilation by a (2k+1)^2 square (exact; the border replicated, which adds no value
    the cut window does not hold)."""
    square = np.ones((2 * k + 1, 2 * k + 1), np.uint8)
    return (cv2.erode(lo, square, borderType=cv2.BORDER_REPLICATE),
            cv2.dilate(hi, square, borderType=cv2.BORDER_REPLICATE))


@dataclass(frozen=True)
class TileMap:
    """Per-tile CoC ranges and classes of an (H, W) CoC map; tile arrays are (ceil(H/t), ceil(W/t)).

    Attributes
    ----------
    shape : (H, W) of the CoC map, pixels
    tile_px : tile side, pixels
    coc_min, coc_max : float32, signed CoC range of each tile's own pixels, pixels
    copy : bool, in focus and out of reach of every blurred foreground pixel
    """

    shape: tuple
    tile_px: int
    coc_min: np.ndarray
    coc_max: np.ndarray
    copy: np.ndarray

    @property
    def n_tiles(self) -> int:
        return int(self.copy.size)

    def uniform(self, abs_lo_px: float, abs_hi_px: float, side: int, reach_px: float) -> np.ndarray:
        """Uniform tiles of the blur layer abs_lo_px <= |c| < abs_hi_px on *side* (+1 behind, -1 in front of focus).

        A tile is uniform when every pixel within *reach_px* of it (its own included; the
        neighbourhood is rounded up to whole tiles) lies in the layer and the CoC spread over
        them is at most :data:`UNIFORM_SPREAD` of its mean magnitude. Returns (th, tw) bool.
        """
        k = int(math.ceil(reach_px / self.tile_px))
        wlo, whi = window_range(self.coc_min, self.coc_max, k)
        if side > 0:
            a_lo, a_hi = wlo, whi
        else:
            a_lo, a_hi = -whi, -wlo
        with np.errstate(over="ignore", invalid="ignore"):  # infinite CoC: never uniform
            return (a_lo >= abs_lo_px) & (a_hi < abs_hi_px) & (a_hi - a_lo <= UNIFORM_SPREAD * 0.5 * (a_lo + a_hi))

    def pixel_mask(self, tiles: np.ndarray, window=None) -> np.ndarray:
        """Bool mask of the pixels of the tiles set in *tiles* ((th, tw) bool): (H, W), or only the
        pixels of *window* (a (rows, cols) pair of slices with steps of 1, as used to crop the image)."""
        t = self.tile_px
        (y0, y1, _), (x0, x1, _) = (sl.indices(n) for sl, n in zip(window or (slice(None), slice(None)), self.shape))
        # the tiles the window touches, expanded to pixels, then cut to the window
        sub = tiles[y0 // t:(y1 + t - 1) // t, x0 // t:(x1 + t - 1) // t]
        full = np.repeat(np.repeat(sub, t, axis=0), t, axis=1)
        return full[y0 - (y0 // t) * t:y1 - (y0 // t) * t, x0 - (x0 // t) * t:x1 - (x0 // t) * t]

    def boxes(self, tiles: np.ndarray) -> list:
        """The pixels of the tiles set in *tiles* ((th, tw) bool) as boxes: one (rows, columns) pair of slices per
        run of set tiles along a row of tiles, cut at the map's edge."""
        t = self.tile_px
        h, w = self.shape
        out = []
        for ty in np.flatnonzero(tiles.any(axis=1)):
            row = np.concatenate(([False], tiles[ty], [False]))
            edges = np.flatnonzero(row[1:] != row[:-1])  # starts and ends of the runs, alternately
            rows = slice(int(ty) * t, min(h, (int(ty) + 1) * t))
            out += [(rows, slice(int(a) * t, min(w, int(b) * t))) for a, b in zip(edges[::2], edges[1::2])]
        return out

    def summary(self) -> dict:
        """Plain counts for the pipeline trace."""
        return {"tile_px": self.tile_px, "tiles": self.n_tiles, "copy_tiles": int(self.copy.sum())}


def classify_tiles(signed_coc, *, tile_px: int = TILE_PX, sharp_px: float = 1.0) -> TileMap:
    """Classify the tiles of a signed CoC map (see the module docstring).

    Parameters
    ----------
    signed_coc : (H, W) float array, signed CoC diameter in pixels (< 0 in front of focus); NaN counts as 0
    tile_px : int >= 1, tile side in pixels
    sharp_px : float > 0, pixels with |c| below it are in focus (the renderer's sharp limit)

    Returns
    -------
    TileMap
    """
    coc = np.asarray(signed_coc)
    if coc.ndim != 2 or coc.dtype.kind != "f":
        raise InputError(f"signed_coc must be a 2-D float array; got shape {coc.shape}, dtype {coc.dtype}")
    if isinstance(tile_px, bool) or not isinstance(tile_px, (int, np.integer)) or tile_px < 1:
        raise InputError(f"tile_px must be an integer >= 1; got {tile_px!r}")
    if not (isinstance(sharp_px, (int, float)) and math.isfinite(sharp_px) and sharp_px > 0):
        raise InputError(f"sharp_px must be a finite number > 0; got {sharp_px!r}")
    coc = read_only(np.ascontiguousarray(coc, np.float32))  # one kernel type whatever the caller's flags
    lo, hi, front_r = tile_ranges(coc, int(tile_px), float(sharp_px))
    sharp = (lo > -sharp_px) & (hi < sharp_px)
    copy = sharp & ~_reached_from_front(front_r, int(tile_px))
    return TileMap(coc.shape, int(tile_px), lo, hi, copy)


def warmup() -> None:
    """Compile (or load from numba's cache) the tile kernels on a tiny CoC map: classification and the
    uniform-tile window, which a frame needs only when it has uniform blur."""
    coc = np.zeros((8, 8), np.float32)
    coc[:, 4:] = -6.0
    classify_tiles(coc, tile_px=4).uniform(2.0, 8.0, -1, 3.0)
