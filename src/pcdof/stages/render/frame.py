"""What the physical renderer's layers share: the frame every layer reads and the canvas they are
composited into."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...plans import RenderPlan
from .aperture import RenderAperture
from .tiles import TileMap


@dataclass(frozen=True)
class RenderFrame:
    """What every layer of a render reads: linear colour (H, W, C) float32, footprint radius (H, W),
    layer ids (H, W) int8, the tile map, the plan, the aperture, whether layers extend behind, where
    surfaces end (:func:`pcdof.stages.render.classify.across_jumps`: (H, W) int8, or None when nothing is
    extended) and the frame's layer edges (:func:`pcdof.stages.render.classify.frame_edges`: (2, n) px, in
    front of the focus and behind it)."""

    lin: np.ndarray
    radius: np.ndarray
    layer: np.ndarray
    tiles: TileMap
    plan: RenderPlan
    aperture: RenderAperture
    extend_behind: bool
    across: np.ndarray | None
    edges: np.ndarray


@dataclass(frozen=True)
class FrameLayers:
    """A frame's classification into layers (:func:`pcdof.stages.render.physical.classify_frame`): the layer edges
    (2, n) px, footprint radius (H, W) float32 and layer ids (H, W) int8 of the frame widened by *border_px*, the
    layers' keys, pixel counts, largest radii and bounding boxes, the tile map, and where surfaces end (``across``:
    (H, W) int8, or None when nothing is extended). Plain data: made once, read by the render."""

    edges: np.ndarray
    radius: np.ndarray
    layer: np.ndarray
    keys: np.ndarray
    counts: np.ndarray
    r_maxes: np.ndarray
    boxes: np.ndarray
    tiles: TileMap
    across: np.ndarray | None
    border_px: int
    extend_behind: bool


@dataclass(frozen=True)
class Canvas:
    """Front-to-back compositing state: (H, W, C) premultiplied colour and (H, W) opacity composited so far
    (the transmittance left is 1 - opacity)."""

    acc: np.ndarray
    opacity: np.ndarray

    @classmethod
    def start(cls, lin: np.ndarray, tiles: TileMap, copy_tiles: bool) -> "Canvas":
        """The canvas before any layer of the render of *lin* (H, W, C) float32: nothing composited, except the
        copy tiles (in focus and out of every foreground's reach), opaque from the start with the input's
        colour, so nothing is composited there and the normalisation returns the input."""
        h, w, nc = lin.shape
        acc = np.zeros((h, w, nc), np.float32)
        opacity = np.zeros((h, w), np.float32)
        if copy_tiles:
            for box in tiles.boxes(tiles.copy):
                opacity[box] = 1.0
                acc[box] = lin[box]
        return cls(acc, opacity)


def as_channels(color: np.ndarray) -> np.ndarray:
    """*color* (H, W) or (H, W, C) as (H, W, C): a view with a channel axis of length 1 added to a grey image."""
    return color[:, :, None] if color.ndim == 2 else color
