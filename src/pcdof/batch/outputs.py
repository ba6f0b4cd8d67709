"""Where a batch writes: output names, the check that no output replaces an input, leftover temporary files."""

from __future__ import annotations

import contextlib
import os

from ..errors import InputError
from ..sources.discovery import Sequence

REPORT_NAME = "report.json"
DEPTH_DIR = "depth"


def frame_name(index: int) -> str:
    """Output file name of frame *index*: ``frame_000000.png``."""
    return f"frame_{index:06d}.png"


def _planned_writes(output_dir: str, n_frames: int, save_depth: bool, video: str | None) -> list[tuple[str, str]]:
    """(path, what) of every file a batch would write."""
    from .lock import LOCK_NAME

    writes = [(os.path.join(output_dir, REPORT_NAME), "report.json (-o)"),
              (os.path.join(output_dir, LOCK_NAME), "the batch's lock file (-o)")]
    for i in range(n_frames):
        writes.append((os.path.join(output_dir, frame_name(i)), f"frame {i}'s image (-o)"))
        if save_depth:
            writes.append((os.path.join(output_dir, DEPTH_DIR, frame_name(i)), f"frame {i}'s depth (--save-depth)"))
    if video is not None:
        writes.append((os.path.abspath(str(video)), "the video (--video)"))
    return writes


def check_inputs_kept(sequence: Sequence, output_dir: str, n_frames: int, *, save_depth: bool = False,
                      video: str | None = None, extra_inputs: dict | None = None) -> None:
    """InputError, before any work, when a file the batch would write is one of the batch's input files.

    Paths are compared after resolving symbolic links, and existing files by device and inode (hard
    links), so an output folder equal to or inside the input folder is refused only where a name
    really collides (e.g. inputs ``depth/frame_000001.png``).

    Parameters
    ----------
    sequence : Sequence
    output_dir : str
    n_frames : int, frames to render (outputs ``frame_NNNNNN.png`` for 0..n_frames-1)
    save_depth : bool, also ``depth/frame_NNNNNN.png``
    video : str or None, the video path
    extra_inputs : {label: path} or None, other files read (the calibration, the list file)
    """
    from ..io._files import file_identity

    output_dir = os.path.abspath(os.fspath(output_dir))
    writes = _planned_writes(output_dir, n_frames, save_depth, video)
    inputs = [p for pair in sequence.pairs for p in (pair.color, pair.depth)]
    inputs += [p for p in (extra_inputs or {}).values() if p is not None]
    by_path = {}
    by_inode = {}
    for p in inputs:
        real, inode = file_identity(p)
        by_path.setdefault(real, p)
        if inode is not None:
            by_inode.setdefault(inode, p)
    real_dirs = {}  # an output's folder resolved once; its own name is checked below if it exists
    for path, what in writes:
        folder = os.path.dirname(path)
        if folder not in real_dirs:
            real_dirs[folder] = os.path.realpath(folder)
        hit = by_path.get(os.path.normcase(os.path.join(real_dirs[folder], os.path.basename(path))))
        if hit is None and os.path.lexists(path):
            ident = file_identity(path)
            hit = by_path.get(ident[0]) or (by_inode.get(ident[1]) if ident[1] is not None else None)
        if hit is not None:
            raise InputError(f"refusing to overwrite the input file {hit!r} with {what}; "
                             f"choose an output folder (-o) and --video outside the input files")


def sweep_temp_files(output_dir: str, n_frames: int) -> int:
    """Remove the temporary files of the batch's own outputs in *output_dir* (frames, depth, report.json).

    Only names :func:`pcdof.io.writers` gives the temporary files of this batch's outputs are removed
    (``.frame_NNNNNN.png.*.tmp``, ``.report.json.*.tmp``), never another file; the caller holds the
    folder's lock, so no running batch owns them. Returns how many were removed.
    """
    import re

    pattern = re.compile(r"\.(frame_\d{6,}\.png|report\.json)\..+\.tmp")
    removed = 0
    for folder in (output_dir, os.path.join(output_dir, DEPTH_DIR)):
        try:
            names = os.listdir(folder)
        except OSError:
            continue
        for name in names:
            if pattern.fullmatch(name) is None:
                continue
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(folder, name))
                removed += 1
    return removed
