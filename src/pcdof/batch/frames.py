"""Reading a batch's frames: image files, or the frames of a recording kept open per process."""

from __future__ import annotations

import os

import numpy as np

from ..camera import RGBDFrame, Rig
from ..errors import InputError
from ..sources.discovery import FramePair, Sequence


def read_frame(pair: FramePair, rig: Rig) -> RGBDFrame:
    """Read one colour/depth pair into an :class:`~pcdof.camera.RGBDFrame` of *rig* (no calibration I/O).

    A recording's frame (``pair.frame`` set) is read through its source, kept open per process.
    """
    from .. import io

    if pair.frame is not None:
        frame = _recording(pair.color).frame(pair.frame)
        return RGBDFrame(frame.color, frame.depth_m, rig, n_invalid_depth=frame.n_invalid_depth)
    color = io.read_color(pair.color)
    depth = io.read_depth(pair.depth, depth_scale=rig.depth_scale)
    return RGBDFrame(color, depth, rig)


def read_depth_m(pair: FramePair, rig: Rig) -> np.ndarray:
    """The depth image of one pair, metres, on the depth camera's grid (checked against *rig*)."""
    from .. import io

    if pair.frame is not None:
        depth = _recording(pair.color).frame(pair.frame).depth_m
    else:
        depth = io.read_depth(pair.depth, depth_scale=rig.depth_scale)
    if depth.shape != rig.depth.shape:
        raise InputError(f"depth must be (H, W) = {rig.depth.shape}; got {depth.shape}")
    return depth


# the recording this process reads frames from: {path: FrameSource}, at most one open at a time
_OPEN_RECORDING: dict = {}


def _recording(path: str):
    """The recording *path* opened once per process (its own calibration: the job's rig replaces it)."""
    from ..sources import open_source

    if path not in _OPEN_RECORDING:
        for source in _OPEN_RECORDING.values():
            source.close()
        _OPEN_RECORDING.clear()
        _OPEN_RECORDING[path] = open_source(path)
    return _OPEN_RECORDING[path]


def open_recording(path: str, *, calib: str | None = None, max_difference: float | None = None) -> tuple:
    """The frames of the recording *path* as a :class:`Sequence` of indexed pairs, and its rig.

    *calib* (a calibration file) replaces the recording's calibration; *max_difference* (seconds) is
    its colour/depth pairing tolerance (None: one frame period of the slower stream).
    """
    from ..sources import open_source

    path = os.path.abspath(path)
    with open_source(path, calib=calib, max_difference_s=max_difference) as src:
        times = [(float(src.color_times[c]), float(src.depth_times[d])) for c, d in src.pairs]
        pairs = tuple(FramePair(str(i), path, path, tc, td, frame=i) for i, (tc, td) in enumerate(times))
        return Sequence(pairs, src.format, os.path.dirname(path)), src.rig
