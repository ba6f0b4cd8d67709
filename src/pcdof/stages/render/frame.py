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
    layer ids (H, W) int8, the tile map, the plan, the aperture, whether layers extend behind, and where
    surfaces end (:func:`pcdof.stages.render.classify.across_jumps`: (H, W) int8, or None when nothing is
    extended)."""

    lin: np.ndarray
    radius: np.ndarray
    layer: np.ndarray
    tiles: TileMap
    plan: RenderPlan
    aperture: RenderAperture
    extend_behind: bool
    across: np.ndarray | None = None


@dataclass(frozen=True)
class Canvas:
    """Front-to-back compositing state, (H, W, C) premultiplied colour, (H, W) opacity and transmittance."""

    acc: np.ndarray
    acc_a: np.ndarray
    trans: np.ndarray

    @classmethod
    def start(cls, shape, tiles: TileMap, copy_tiles: bool) -> "Canvas":
        h, w, nc = shape
        trans = np.ones((h, w), np.float32)
        # copy tiles: in focus and out of every foreground's reach, so opaque from the start; nothing
        # is composited there and the normalisation returns the input (acc_a stays 0)
        if copy_tiles and tiles.copy.any():
            trans[tiles.pixel_mask(tiles.copy)] = 0.0
        return cls(np.zeros((h, w, nc), np.float32), np.zeros((h, w), np.float32), trans)


def as_channels(color: np.ndarray) -> np.ndarray:
    """*color* (H, W) or (H, W, C) as (H, W, C): a view with a channel axis of length 1 added to a grey image."""
    return color[:, :, None] if color.ndim == 2 else color
