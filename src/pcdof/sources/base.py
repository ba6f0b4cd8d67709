"""The frame-source seam: anything that yields colour + depth frames of one rig.

A :class:`FrameSource` knows its :class:`~pcdof.camera.Rig`, how many frames it has, and how to read
frame *i* as a :class:`SourceFrame` (colour, depth in metres on the depth camera's grid, the two
timestamps when the source has them). A new input kind is one module with one subclass that
implements ``__len__`` and ``_read(i)`` (and ``_close`` if it holds a file open), plus an entry in
:data:`pcdof.sources.SOURCES`, whose ``can_open`` lets :func:`pcdof.sources.open_source` pick it.

Two families share more code: :class:`RecordingSource` (a file with a colour and a depth stream,
paired by timestamp: ``.mkv``, ``.bag``) and :class:`pcdof.sources.files.FileSource` (colour and
depth image files with a calibration file: a pair, a folder, a TUM folder, a list file).
"""

from __future__ import annotations

import abc
import dataclasses
import math
import os

import numpy as np

from ..camera import Rig, RGBDFrame
from ..errors import CalibrationError, ImageReadError, InputError, PcdofError, library_errors


@dataclasses.dataclass(frozen=True, eq=False)
class SourceFrame:
    """One paired colour and depth frame of a source.

    Attributes
    ----------
    index : int, the frame's position in the source (0-based)
    color : (H, W, 3) ndarray, RGB, ``rig.color`` size: uint8 from recordings; from image files the
        file's own type, as :func:`pcdof.io.read_color` gives it (uint8, uint16 or float32)
    depth_m : (h, w) float32 ndarray, metres, 0 = unknown, in the depth camera's pixel grid
    rig : Rig
    color_time_s, depth_time_s : float or None, seconds on the source's clock (None: the source has no times)
    n_invalid_depth : int, depth values the reader found NaN, inf or negative and set to 0
    """

    index: int
    color: np.ndarray
    depth_m: np.ndarray
    rig: Rig
    color_time_s: float | None
    depth_time_s: float | None
    n_invalid_depth: int = 0

    @property
    def timestamp_s(self) -> float | None:
        """The colour image's time, seconds: the frame's time (depth-of-field images are colour images)."""
        return self.color_time_s

    def rgbd(self) -> RGBDFrame:
        """The frame as the :class:`~pcdof.camera.RGBDFrame` the rest of pcdof takes."""
        return RGBDFrame(self.color, self.depth_m, self.rig, n_invalid_depth=self.n_invalid_depth)


def frame_period_s(times) -> float | None:
    """Median interval of a sorted stream of timestamps, seconds (None for fewer than two)."""
    t = np.asarray(times, dtype=np.float64)
    if t.size < 2:
        return None
    gaps = np.diff(np.sort(t))
    gaps = gaps[gaps > 0]
    return float(np.median(gaps)) if gaps.size else None


def check_max_difference(max_difference_s) -> float:
    """*max_difference_s* as a float; InputError unless it is a finite number of seconds > 0."""
    if isinstance(max_difference_s, bool) or not isinstance(max_difference_s, (int, float, np.floating)) or not (
            math.isfinite(max_difference_s) and max_difference_s > 0):
        raise InputError(f"max_difference_s must be a finite number of seconds > 0; got {max_difference_s!r}")
    return float(max_difference_s)


def pair_by_time(color_times, depth_times, *, max_difference_s: float | None = None,
                 periods_s=(None, None)) -> tuple[np.ndarray, float]:
    """Pair colour and depth frames by nearest timestamp, each frame used at most once.

    Parameters
    ----------
    color_times, depth_times : (n,), (m,) float ndarray, seconds
    max_difference_s : float, largest accepted |t_color - t_depth|; default one frame period of the
        slower stream (from *periods_s*, else the median interval): streams at that rate always have a
        frame within half a period, and a whole one allows for a dropped frame or a late start
    periods_s : (float or None, float or None), the streams' nominal frame periods (1 / fps)

    Returns
    -------
    pairs : (k, 2) int64 ndarray, (colour index, depth index), in colour-time order
    max_difference_s : float, the tolerance used
    """
    from .discovery import associate  # TUM associate.py's greedy nearest-time pairing

    if max_difference_s is None:
        periods = [p if p else frame_period_s(t) for p, t in zip(periods_s, (color_times, depth_times))]
        periods = [p for p in periods if p]
        max_difference_s = max(periods) if periods else math.inf
    else:
        max_difference_s = check_max_difference(max_difference_s)
    if math.isinf(max_difference_s):  # one frame in each stream, no rate known: they belong together
        return np.zeros((1, 2), np.int64) if len(color_times) and len(depth_times) else np.zeros((0, 2), np.int64), \
            max_difference_s
    return associate(color_times, depth_times, max_difference=float(max_difference_s)), float(max_difference_s)


class FrameSource(abc.ABC):
    """A sequence of paired colour and depth frames from one rig.

    A subclass sets :attr:`format` (its :data:`~pcdof.sources.SOURCES` name), calls
    ``super().__init__(path, rig)``, and implements ``__len__`` and :meth:`_read`; :meth:`frame`
    checks the index and the image sizes around it. :meth:`open` (the registry's opener) builds it
    from a path and the caller's options.

    Use as a context manager (``with open_source(path) as src: ...``), or call :meth:`close`.

    Parameters
    ----------
    path : str, the recording, folder or file the frames come from (for messages)
    rig : Rig, the calibration of every frame
    calibration_from : str, where the rig came from (``"source"``, or the calibration file given)
    """

    #: the registry name of the format
    format: str = ""

    def __init__(self, path: str, rig: Rig, *, calibration_from: str = "source") -> None:
        if not isinstance(rig, Rig):
            raise InputError(f"{path}: a source's rig must be a Rig; got {type(rig).__name__}")
        self.path = path
        self.rig = rig
        self.calibration_from = calibration_from

    @classmethod
    def open(cls, path: str, *, calib=None, depth_scale: float | None = None,
             max_difference_s: float | None = None) -> "FrameSource":
        """Open *path* with the options of :func:`pcdof.sources.open_source` (the registry's opener)."""
        raise NotImplementedError(f"{cls.__name__} has no opener; give its SourceKind one")

    @abc.abstractmethod
    def __len__(self) -> int:
        """Number of frames (at least 1)."""

    @abc.abstractmethod
    def _read(self, i: int) -> SourceFrame:
        """Frame *i*, 0 <= i < len: PcdofError naming what could not be read."""

    def _where(self, i: int) -> str:
        """Prefix of the errors of frame *i* (names the source and the frame)."""
        return f"{self.path}: frame {i}: "

    def _frame_times(self) -> np.ndarray:
        """(len,) float64 colour times of the frames, seconds; NaN where the source has none."""
        return np.full(len(self), np.nan)

    def _info(self) -> dict:
        """Format-specific entries of :meth:`info` (streams, pairing, files)."""
        return {}

    def _close(self) -> None:
        """Release what the source holds open (nothing by default)."""

    def __iter__(self):
        for i in range(len(self)):
            yield self.frame(i)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the file; frames can no longer be read."""
        self._close()

    def check_index(self, index) -> int:
        """*index* as an int in [-len, len); InputError naming the source otherwise."""
        n = len(self)
        if isinstance(index, (bool, np.bool_)) or not isinstance(index, (int, np.integer)):
            raise InputError(f"{self.path}: frame index must be an integer; got {index!r}")
        if not -n <= index < n:
            raise InputError(f"{self.path}: frame index {index} is out of range: it has {n} frame"
                             f"{'s' if n != 1 else ''} (0..{n - 1})")
        return int(index) % n

    def frame(self, index) -> SourceFrame:
        """Read frame *index*; the reader's error class, its message prefixed with the source and the frame."""
        i = self.check_index(index)
        try:
            with library_errors("cannot be read"):
                frame = self._read(i)
        except PcdofError as err:
            raise type(err)(f"{self._where(i)}{err}") from None
        shapes = ((frame.color.shape[:2], frame.rig.color.shape, "colour"),
                  (frame.depth_m.shape, frame.rig.depth.shape, "depth"))
        for got, want, what in shapes:
            if tuple(got) != tuple(want):
                raise ImageReadError(f"{self._where(i)}the {what} image is {got[1]}x{got[0]}; the "
                                     f"calibration says {want[1]}x{want[0]}")
        return frame

    def index_at(self, time_s: float) -> int:
        """Index of the frame whose colour time is nearest *time_s* (seconds on the source's clock)."""
        if isinstance(time_s, bool) or not isinstance(time_s, (int, float, np.number)) or not math.isfinite(time_s):
            raise InputError(f"time_s must be a finite number of seconds; got {time_s!r}")
        times = self._frame_times()
        if np.isnan(times).any():
            raise InputError(f"{self.path}: its frames have no timestamps ({self.format}); choose a frame by index")
        return int(np.argmin(np.abs(times - float(time_s))))

    def frame_at(self, time_s: float) -> SourceFrame:
        """The frame whose colour time is nearest *time_s*."""
        return self.frame(self.index_at(time_s))

    def info(self) -> dict:
        """Plain description: format, frames, calibration and the format's own entries (JSON-ready)."""
        return {"path": self.path, "format": self.format, "frames": len(self), **self._info(),
                "calibration_from": self.calibration_from, "baseline_mm": self.rig.baseline_m * 1000.0,
                "calibration": self.rig.to_dict()}


@dataclasses.dataclass(frozen=True)
class RecordedStreams:
    """What a recording says about its streams without its calibration: image shapes and depth units.

    Attributes
    ----------
    color_shape, depth_shape : (height, width) of the colour and depth images, or None when unknown
    depth_scale : float, metres per unit of the recording's integer depth
    """

    color_shape: tuple[int, int] | None
    depth_shape: tuple[int, int] | None
    depth_scale: float

    @classmethod
    def of(cls, rig: Rig) -> "RecordedStreams":
        """The streams a recording's own calibration describes."""
        return cls(rig.color.shape, rig.depth.shape, rig.depth_scale)


class RecordingSource(FrameSource):
    """A recording file with a colour and a depth stream, paired by timestamp (``.mkv``, ``.bag``).

    Subclasses pair their streams once, in the constructor, and call ``super().__init__`` with the
    rig, the streams' timestamps and the pairs; they implement the reading of one colour or depth
    image by its stream index (:meth:`_read_color`, :meth:`_read_depth`) and :meth:`_streams`. When a
    calibration replaces the recording's (*override*), a subclass reads none of its own: it passes
    ``rig=None`` and the :class:`RecordedStreams` that the override is checked against.
    """

    def __init__(self, path: str, rig: Rig | None, color_times, depth_times, pairs, *, max_difference_s: float,
                 override: Rig | None = None, override_path: str | None = None,
                 streams: RecordedStreams | None = None) -> None:
        self.color_times = np.asarray(color_times, dtype=np.float64)
        self.depth_times = np.asarray(depth_times, dtype=np.float64)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self.max_difference_s = max_difference_s
        calibration_from = "recording"
        if override is not None:
            rig = _override(streams or RecordedStreams.of(rig), override, override_path, path)
            calibration_from = override_path or "caller"
        elif rig is None:
            raise CalibrationError(f"{path}: the recording's calibration was not read and none replaces it")
        super().__init__(path, rig, calibration_from=calibration_from)
        if len(self.pairs) == 0:
            raise ImageReadError(f"{path}: no colour frame has a depth frame within {max_difference_s:.4g} s "
                                 f"({len(self.color_times)} colour, {len(self.depth_times)} depth frames)")

    @classmethod
    def open(cls, path: str, *, calib=None, depth_scale: float | None = None,
             max_difference_s: float | None = None) -> "RecordingSource":
        """Open the recording *path*; *calib* (a calibration file) replaces the recording's calibration.

        The calibration file is read first, and the recording's own calibration is then not needed
        (a recording that lacks it opens with *calib*). Any error of the library that reads the file
        is an :class:`~pcdof.errors.ImageReadError` naming *path*.
        """
        if depth_scale is not None:
            raise InputError(f"depth_scale applies to integer depth files; the recording {path} carries its own "
                             f"depth units (got depth_scale={depth_scale!r})")
        rig = calib_path = None
        if calib is not None:
            from ..io import read_calibration
            from ..io._files import fspath

            calib_path = fspath(calib, name="calib")
            rig = read_calibration(calib_path, depth_scale=1.0)  # the scale is the recording's; see _override
        with library_errors(f"cannot read recording {path}"):
            return cls(path, rig=rig, calib_path=calib_path, max_difference_s=max_difference_s)

    def __len__(self) -> int:
        return len(self.pairs)

    def _read(self, i: int) -> SourceFrame:
        ci, di = (int(v) for v in self.pairs[i])
        return SourceFrame(i, self._read_color(ci), self._read_depth(di), self.rig, float(self.color_times[ci]),
                           float(self.depth_times[di]))

    def _frame_times(self) -> np.ndarray:
        return self.color_times[self.pairs[:, 0]]

    def _info(self) -> dict:
        paired = np.abs(self.color_times[self.pairs[:, 0]] - self.depth_times[self.pairs[:, 1]])
        n = len(self)
        return {
            "streams": self._streams(),
            "pairing": {"max_difference_s": self.max_difference_s, "largest_difference_s": float(paired.max()),
                        "unpaired_color": len(self.color_times) - n, "unpaired_depth": len(self.depth_times) - n},
        }

    @abc.abstractmethod
    def _read_color(self, i: int) -> np.ndarray:
        """Colour image *i* of the colour stream: (H, W, 3) uint8 RGB; PcdofError if undecodable."""

    @abc.abstractmethod
    def _read_depth(self, i: int) -> np.ndarray:
        """Depth image *i* of the depth stream: (h, w) float32 metres, 0 = unknown; PcdofError if undecodable."""

    @abc.abstractmethod
    def _streams(self) -> dict:
        """name -> plain dict (encoding, size, frames, fps, ...) of the source's streams."""


def _override(recorded: RecordedStreams, rig: Rig, override_path: str | None, path: str) -> Rig:
    """*rig* in place of the recording's calibration: same image sizes required; depth units stay the recording's."""
    where = override_path or "calib"
    for name, shape in (("color", recorded.color_shape), ("depth", recorded.depth_shape)):
        a = getattr(rig, name)
        if shape is not None and a.shape != tuple(shape):
            raise CalibrationError(f"{where}: its {name} camera is {a.width}x{a.height} but the {name} stream of "
                                   f"{path} is {shape[1]}x{shape[0]}")
    # the recording's integers are converted with the recording's own units; a calibration file's
    # depth_scale describes integer depth *files*, which a recording is not
    return dataclasses.replace(rig, depth_scale=recorded.depth_scale)


def float32_value(value: float) -> float:
    """The shortest decimal that reads back as the same float32 (0.0010000000474974513 -> 0.001)."""
    return float(str(np.float32(value)))


def file_size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError as err:
        raise ImageReadError(f"cannot read recording {path}: {err.strerror or err}") from None
