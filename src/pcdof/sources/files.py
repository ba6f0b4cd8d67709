"""Frames stored as image files: colour and depth files, paired, with one calibration file.

:class:`FileSource` is what the file layouts share (:mod:`~pcdof.sources.pair`,
:mod:`~pcdof.sources.folder`, :mod:`~pcdof.sources.tum`, :mod:`~pcdof.sources.listfile`): the
pairs come from :func:`pcdof.sources.discovery.discover` (or one given pair), the rig from
:func:`pcdof.sources.discovery.load_rig`, and every frame is read by :func:`pcdof.io.load_frame` with that
rig's depth scale, so a frame read through a source is the frame ``load_frame`` gives for its files.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from .base import FrameSource, SourceFrame


class FileSource(FrameSource):
    """The frames of a :class:`~pcdof.sources.discovery.Sequence` of colour/depth files and one calibration.

    Parameters
    ----------
    path : str, the source as the caller named it (folder, list file, colour image)
    sequence : Sequence, the colour/depth file pairs, in order (at least one)
    calib : str or os.PathLike or None, calibration file; None: one of
        :data:`pcdof.sources.discovery.CALIBRATION_NAMES` in ``sequence.root``
    depth_scale : float or None, metres per unit of integer depth files; overrides the calibration's,
        which overrides the layout's default (TUM: 0.0002)
    """

    def __init__(self, path: str, sequence, calib=None, *, depth_scale: float | None = None) -> None:
        from .discovery import find_calibration, load_rig
        from ..io._files import fspath

        if not len(sequence):
            raise InputError(f"{path}: no colour/depth pairs")
        calib_path = find_calibration(sequence) if calib is None else fspath(calib, name="calib")
        super().__init__(path, load_rig(sequence, calib_path, depth_scale=depth_scale), calibration_from=calib_path)
        self.sequence = sequence
        self.calib_path = calib_path

    def __len__(self) -> int:
        return len(self.sequence)

    def _read(self, i: int) -> SourceFrame:
        from ..io import load_frame

        pair = self.sequence.pairs[i]
        frame = load_frame(pair.color, pair.depth, self.calib_path, depth_scale=self.rig.depth_scale)
        return SourceFrame(i, frame.color, frame.depth_m, frame.rig, _seconds(pair.color_time),
                           _seconds(pair.depth_time), frame.n_invalid_depth)

    def _where(self, i: int) -> str:
        pair = self.sequence.pairs[i]
        return f"{self.path}: frame {i} ({self.sequence.relative(pair.color)}, {self.sequence.relative(pair.depth)}): "

    def _frame_times(self) -> np.ndarray:
        return np.array([math.nan if p.color_time is None else p.color_time for p in self.sequence.pairs])

    def _info(self) -> dict:
        seq = self.sequence
        streams = {name: {"width": cam.width, "height": cam.height, "frames": len(seq)}
                   for name, cam in (("color", self.rig.color), ("depth", self.rig.depth))}
        return {"layout": seq.layout, "root": seq.root, "streams": streams,
                "pairing": {"unpaired_color": seq.unmatched_color, "unpaired_depth": seq.unmatched_depth}}


def _seconds(t: float | None) -> float | None:
    return None if t is None else float(t)


def discovered(path, layouts: tuple[str, ...], what: str, **options):
    """:func:`pcdof.sources.discovery.discover` of *path* (with *options*), checked to be one of *layouts*.

    Returns
    -------
    (str, Sequence), the path as a string and its pairs
    """
    from .discovery import discover
    from ..io._files import fspath

    path = fspath(path, name="path")
    seq = discover(path, **options)
    if seq.layout not in layouts:
        raise InputError(f"{path} is not {what}: its files pair as the {seq.layout!r} layout")
    return path, seq


def is_text(head: bytes) -> bool:
    """Whether the first bytes of a file read as UTF-8 text (no NUL; a character cut at the end is fine)."""
    if not head or b"\0" in head:
        return False
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as err:
        return err.start >= len(head) - 3 and err.reason == "unexpected end of data"
    return True
