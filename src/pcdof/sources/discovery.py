"""Find the colour/depth pairs of a sequence and the rig they were taken with.

Supported inputs (:func:`discover` tells them apart):

``folder with color/ and depth/``
    ``color/NNNN.png`` + ``depth/NNNN.png`` (``rgb/`` is accepted for ``color/``). Files are
    paired by their stem, or -- when the two folders name files differently, e.g.
    ``color/frame-0001.jpg`` and ``depth/depth-0001.png`` -- by the last number in the stem.
``flat folder of *_color / *_depth files``
    ``0001_color.png`` + ``0001_depth.png`` (``_rgb`` is accepted for ``_color``), paired by the
    part before the suffix.
``TUM RGB-D layout``
    a folder with ``rgb.txt`` and ``depth.txt`` (lines ``timestamp path``, ``#`` comments), as
    distributed by the TUM RGB-D benchmark. Colour and depth are paired by nearest timestamp
    within a tolerance (default 0.02 s), each depth image used at most once, exactly as TUM's
    ``associate.py``; pairs are kept in colour-time order, unmatched images are counted and dropped.
    TUM depth PNGs store 5000 units per metre, so the default depth scale is 0.0002 m per unit
    unless the calibration file states its own ``depth_scale``.
``list file``
    a text file with one frame per line, ``color_path depth_path`` (paths relative to the list
    file, separated by spaces, tabs or commas; quote paths that hold those; ``#`` at the start of
    a field starts a comment, see :func:`split_fields`), or the four columns that ``associate.py``
    writes: ``t_color color_path t_depth depth_path``.

Frames are ordered by their pairing key (numbers numerically) or by colour timestamp.
"""

from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass

import numpy as np

from ..camera import Rig
from ..errors import ImageReadError, InputError

log = logging.getLogger("pcdof.batch")

#: File suffixes taken as images when a folder is scanned.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".ppm", ".pgm", ".exr", ".npy")
#: TUM RGB-D depth PNGs: 5000 units per metre.
TUM_DEPTH_SCALE = 1.0 / 5000.0
#: Default largest colour/depth timestamp difference for a TUM pair, seconds (TUM associate.py's default).
DEFAULT_MAX_DIFFERENCE_S = 0.02
#: Calibration file names looked for in the input folder when none is given.
CALIBRATION_NAMES = ("calib.json", "calibration.json", "calib.yaml", "calib.yml", "calib.xml", "intrinsics.json")

_COLOR_DIRS = ("color", "rgb")
_COLOR_TAGS = ("_color", "_rgb")
_DEPTH_TAG = "_depth"


@dataclass(frozen=True)
class FramePair:
    """One colour image and the depth image that goes with it.

    Parameters
    ----------
    key : str, what paired them (shared stem, number, or colour timestamp)
    color, depth : str, absolute paths
    color_time, depth_time : float or None, seconds (TUM timestamps)
    frame : int or None, the frame's index in a recording file (``.mkv``, ``.bag``; *color* and *depth*
        are then that file), read through :func:`pcdof.sources.open_source`
    """

    key: str
    color: str
    depth: str
    color_time: float | None = None
    depth_time: float | None = None
    frame: int | None = None


@dataclass(frozen=True, eq=False)
class Sequence:
    """The frames of a sequence, in order.

    Parameters
    ----------
    pairs : tuple of FramePair
    layout : str, "folders", "suffixes", "tum", "list", or a recording's format ("realsense-bag", "azure-kinect")
    root : str, absolute folder the input paths are relative to (for reports)
    default_depth_scale : float or None, metres per depth unit implied by the layout (TUM: 0.0002)
    unmatched_color, unmatched_depth : int, images that found no partner and were dropped
    """

    pairs: tuple[FramePair, ...]
    layout: str
    root: str
    default_depth_scale: float | None = None
    unmatched_color: int = 0
    unmatched_depth: int = 0

    def __len__(self) -> int:
        return len(self.pairs)

    def relative(self, path: str) -> str:
        """*path* relative to the input root (for reports)."""
        return os.path.relpath(path, self.root)


# --------------------------------------------------------------------------------- association
def associate(first_times, second_times, *, max_difference: float = DEFAULT_MAX_DIFFERENCE_S,
              offset: float = 0.0) -> np.ndarray:
    """Pair two timestamp lists by nearest time, each entry used at most once (TUM ``associate.py``).

    All pairs with ``|a - (b + offset)| < max_difference`` are candidates; they are taken greedily
    from the smallest difference up, skipping pairs whose ``a`` or ``b`` is already used.

    Parameters
    ----------
    first_times, second_times : (n,), (m,) float ndarray, seconds
    max_difference : float, seconds (> 0)
    offset : float, seconds added to the second list's times

    Returns
    -------
    (k, 2) int64 ndarray of indices (i into first, j into second), sorted by first time
    """
    a = np.asarray(first_times, dtype=np.float64).ravel()
    b = np.asarray(second_times, dtype=np.float64).ravel() + float(offset)
    if not (np.isfinite(max_difference) and max_difference > 0):
        raise InputError(f"max_difference must be a finite number of seconds > 0; got {max_difference!r}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise InputError("timestamps must be finite numbers")
    if a.size == 0 or b.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    order_b = np.argsort(b, kind="stable")
    sb = b[order_b]
    lo = np.searchsorted(sb, a - max_difference, side="left")
    hi = np.searchsorted(sb, a + max_difference, side="right")
    counts = hi - lo
    ii = np.repeat(np.arange(a.size), counts)
    starts = np.repeat(lo - np.cumsum(np.concatenate([[0], counts[:-1]])), counts)
    jj = order_b[starts + np.arange(ii.size)]
    diff = np.abs(a[ii] - b[jj])
    keep = diff < max_difference
    ii, jj, diff = ii[keep], jj[keep], diff[keep]
    # smallest difference first; ties broken by first time then second time, as sorting tuples does
    order = np.lexsort((b[jj], a[ii], diff))
    used_a = np.zeros(a.size, bool)
    used_b = np.zeros(b.size, bool)
    out = []
    for k in order:
        i, j = ii[k], jj[k]
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            out.append((i, j))
    pairs = np.array(out, dtype=np.int64).reshape(-1, 2)
    return pairs[np.lexsort((pairs[:, 1], a[pairs[:, 0]]))] if len(pairs) else pairs


def read_tum_list(path: str) -> list[tuple[float, str]]:
    """Read a TUM ``rgb.txt`` / ``depth.txt``: ``timestamp path [...]`` lines, ``#`` comments.

    Returns
    -------
    list of (timestamp seconds, absolute path)
    """
    base = os.path.dirname(os.path.abspath(path))
    out = []
    for lineno, fields in _read_lines(path):
        try:
            t = float(fields[0])
        except ValueError:
            raise InputError(f"{path}:{lineno}: expected 'timestamp path'; got {' '.join(fields)!r}") from None
        if len(fields) < 2:
            raise InputError(f"{path}:{lineno}: expected 'timestamp path'; got only {fields[0]!r}")
        out.append((t, os.path.normpath(os.path.join(base, fields[1]))))
    return out


def _read_lines(path: str):
    from ..io._files import read_text

    lines = read_text(path, "list").splitlines()  # a regular UTF-8 file without NUL bytes, or ImageReadError
    for lineno, line in enumerate(lines, 1):
        try:
            fields = split_fields(line)
        except InputError as err:
            raise InputError(f"{path}:{lineno}: {err}") from None
        if fields:
            yield lineno, fields


#: Field separators of list files: whitespace, and commas (TUM's associate.py accepts commas and tabs).
_SEPARATORS = " \t\r\n\f\v,"


def split_fields(line: str) -> list[str]:
    """Fields of one list-file line, shell-like.

    Fields are separated by whitespace or commas; ``'...'`` and ``"..."`` quote (separators and
    ``#`` inside quotes are part of the field); a backslash outside single quotes escapes the next
    character (inside double quotes only ``"`` and ``\\``); ``#`` starts a comment only at the start
    of a field, so ``take#1.png`` is a path.

    Examples
    --------
    >>> split_fields('"my take/f#3.png" "d,3.png"  # frame 3')
    ['my take/f#3.png', 'd,3.png']
    >>> split_fields("take#1_c.png,take#1_d.png")
    ['take#1_c.png', 'take#1_d.png']
    """
    fields: list[str] = []
    field: list[str] = []
    in_field, quote, chars = False, None, iter(line)
    for ch in chars:
        if ch == "\\" and quote != "'":
            nxt = next(chars, None)
            if nxt is None:
                raise InputError("a backslash ends the line; nothing follows it to escape")
            if quote == '"' and nxt not in '"\\':
                field.append(ch)  # as in a shell: inside double quotes, other backslashes stay
            field.append(nxt)
            in_field = True
        elif quote:
            if ch == quote:
                quote = None
            else:
                field.append(ch)
        elif ch in "'\"":
            quote, in_field = ch, True
        elif ch in _SEPARATORS:
            if in_field:
                fields.append("".join(field))
                field, in_field = [], False
        elif ch == "#" and not in_field:
            break  # a comment: the rest of the line
        else:
            field.append(ch)
            in_field = True
    if quote:
        raise InputError(f"no closing quotation mark ({quote})")
    if in_field:
        fields.append("".join(field))
    return fields


# --------------------------------------------------------------------------------- discovery
def discover(path: str, *, max_difference: float = DEFAULT_MAX_DIFFERENCE_S) -> Sequence:
    """Find the frames of the sequence at *path* (any layout in this module's docstring).

    Parameters
    ----------
    path : str, a folder or a list file
    max_difference : float, seconds, TUM colour/depth pairing tolerance

    Returns
    -------
    Sequence (unmatched images are logged and counted)
    """
    from ..io._files import fspath

    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"input must be a folder or list file path; got {type(path).__name__}")
    path = os.path.abspath(fspath(path, name="input"))
    if os.path.basename(path) in ("rgb.txt", "depth.txt"):  # a TUM list given directly: use its folder
        path = os.path.dirname(path)
    if os.path.isfile(path):
        seq = _discover_list(path)
    elif os.path.isdir(path):
        if os.path.isfile(os.path.join(path, "rgb.txt")) and os.path.isfile(os.path.join(path, "depth.txt")):
            seq = _discover_tum(path, max_difference)
        elif any(os.path.isdir(os.path.join(path, d)) for d in _COLOR_DIRS) and os.path.isdir(
            os.path.join(path, "depth")
        ):
            seq = _discover_folders(path)
        else:
            seq = _discover_suffixes(path)
    elif os.path.lexists(path):
        raise ImageReadError(f"input {path!r} is neither a folder nor a regular (list) file")
    else:
        raise ImageReadError(f"input {path!r} does not exist")
    if not seq.pairs:
        raise InputError(
            f"no colour/depth pairs found in {path} (layout {seq.layout!r}; "
            f"{seq.unmatched_color} colour and {seq.unmatched_depth} depth images without a partner)"
        )
    if seq.unmatched_color or seq.unmatched_depth:
        log.warning("%s: %d colour and %d depth images have no partner and are skipped",
                    path, seq.unmatched_color, seq.unmatched_depth)
    return seq


def _discover_tum(root: str, max_difference: float) -> Sequence:
    rgb = read_tum_list(os.path.join(root, "rgb.txt"))
    depth = read_tum_list(os.path.join(root, "depth.txt"))
    ij = associate([t for t, _ in rgb], [t for t, _ in depth], max_difference=max_difference)
    pairs = tuple(
        FramePair(f"{rgb[i][0]:.6f}", rgb[i][1], depth[j][1], rgb[i][0], depth[j][0]) for i, j in ij
    )
    return Sequence(pairs, "tum", root, TUM_DEPTH_SCALE, len(rgb) - len(pairs), len(depth) - len(pairs))


def _discover_list(path: str) -> Sequence:
    base = os.path.dirname(path)
    pairs = []
    for lineno, f in _read_lines(path):
        if len(f) == 2:
            c, d, tc, td = f[0], f[1], None, None
        elif len(f) == 4:
            try:
                tc, td = float(f[0]), float(f[2])
            except ValueError:
                raise InputError(f"{path}:{lineno}: four columns must be 't_color color t_depth depth'") from None
            c, d = f[1], f[3]
        else:
            raise InputError(
                f"{path}:{lineno}: expected 'color_path depth_path' (or 't_color color t_depth depth'); "
                f"got {len(f)} fields"
            )
        pairs.append(FramePair(str(len(pairs)), os.path.normpath(os.path.join(base, c)),
                               os.path.normpath(os.path.join(base, d)), tc, td))
    return Sequence(tuple(pairs), "list", base)


def _images(folder: str) -> list[str]:
    try:
        names = os.listdir(folder)
    except OSError as err:
        raise ImageReadError(f"cannot list {folder}: {err}") from None
    return sorted(n for n in names if os.path.splitext(n)[1].lower() in IMAGE_SUFFIXES
                  and os.path.isfile(os.path.join(folder, n)))


def _sort_key(key: str):
    # natural order: "2" before "10"
    return [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", key) if p]


def _pair_by_key(color: dict[str, str], depth: dict[str, str]) -> tuple[list[FramePair], int, int]:
    keys = sorted(set(color) & set(depth), key=_sort_key)
    pairs = [FramePair(k, color[k], depth[k]) for k in keys]
    return pairs, len(color) - len(keys), len(depth) - len(keys)


def _keyed(folder: str, names: list[str], key_of) -> dict[str, str]:
    out: dict[str, str] = {}
    for n in names:
        k = key_of(n)
        if k is None:
            continue
        if k in out:
            raise InputError(
                f"{folder}: {os.path.basename(out[k])!r} and {n!r} both pair as {k!r}; keep one image per frame"
            )
        out[k] = os.path.join(folder, n)
    return out


def _last_number(stem: str) -> str | None:
    nums = re.findall(r"\d+", stem)
    return str(int(nums[-1])) if nums else None


def _discover_folders(root: str) -> Sequence:
    cdir = next(os.path.join(root, d) for d in _COLOR_DIRS if os.path.isdir(os.path.join(root, d)))
    ddir = os.path.join(root, "depth")
    cnames, dnames = _images(cdir), _images(ddir)
    stem = lambda n: os.path.splitext(n)[0]  # noqa: E731
    color, depth = _keyed(cdir, cnames, stem), _keyed(ddir, dnames, stem)
    pairs, uc, ud = _pair_by_key(color, depth)
    if not pairs and cnames and dnames:
        color, depth = _keyed(cdir, cnames, lambda n: _last_number(stem(n))), _keyed(
            ddir, dnames, lambda n: _last_number(stem(n)))
        pairs, _, _ = _pair_by_key(color, depth)
        uc, ud = len(cnames) - len(pairs), len(dnames) - len(pairs)
    return Sequence(tuple(pairs), "folders", root, None, uc, ud)


def _tagged(name: str, tags) -> str | None:
    stem = os.path.splitext(name)[0]
    for tag in tags:
        if stem.lower().endswith(tag):
            return stem[: -len(tag)]
    return None


def _discover_suffixes(root: str) -> Sequence:
    names = _images(root)
    color = _keyed(root, names, lambda n: _tagged(n, _COLOR_TAGS))
    depth = _keyed(root, names, lambda n: _tagged(n, (_DEPTH_TAG,)))
    pairs, uc, ud = _pair_by_key(color, depth)
    return Sequence(tuple(pairs), "suffixes", root, None, uc, ud)


# --------------------------------------------------------------------------------- calibration
def find_calibration(sequence: Sequence) -> str:
    """The calibration file in the sequence's folder (one of :data:`CALIBRATION_NAMES`)."""
    for name in CALIBRATION_NAMES:
        candidate = os.path.join(sequence.root, name)
        if os.path.isfile(candidate):
            return candidate
    raise InputError(f"no calibration given and none of {', '.join(CALIBRATION_NAMES)} in {sequence.root}; "
                     f"pass --calib")


def load_rig(sequence: Sequence, calib_path: str | None = None, *, depth_scale: float | None = None) -> Rig:
    """Read the sequence's rig once, with the depth scale that applies to its depth files.

    Precedence: *depth_scale* (the caller's override) > the calibration file's own ``depth_scale``
    > the layout's default (TUM: 0.0002 m per unit) > :class:`~pcdof.camera.Rig`'s default.

    Parameters
    ----------
    sequence : Sequence
    calib_path : str or None, calibration file (None = look for one in the input folder)
    depth_scale : float or None, metres per depth unit

    Returns
    -------
    Rig
    """
    from ..io import read_calibration

    path = calib_path if calib_path is not None else find_calibration(sequence)
    # one read, through the guarded reader, whatever decides the depth scale
    return read_calibration(path, depth_scale=depth_scale, default_depth_scale=sequence.default_depth_scale)
