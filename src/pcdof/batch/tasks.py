"""What a batch sends its workers: the shared job, one task per frame, and a frame's report entry."""

from __future__ import annotations

import os
from dataclasses import dataclass

from ..camera import Rig
from ..errors import ImageWriteError
from ..lens import ThinLens
from ..sources.discovery import FramePair


@dataclass(frozen=True, eq=False)
class BatchJob:
    """What every frame of a batch shares (sent to each worker once).

    Parameters
    ----------
    rig : Rig, read once from the calibration
    output_dir : str, absolute
    options : RenderOptions, how every frame is rendered (each frame's lens replaces ``options.lens``)
    save_depth : bool, also write the registered, filled depth (16-bit PNG via :func:`pcdof.io.write_depth`)
    threads : int or None, numba / OpenCV threads per task (None = leave the libraries' defaults)
    parent_pid : int or None, the batch's process: local workers exit when it dies
    """

    rig: Rig
    output_dir: str
    options: object  # RenderOptions (imported lazily: workers load it with the pipeline)
    save_depth: bool = False
    threads: int | None = None
    parent_pid: int | None = None


@dataclass(frozen=True)
class FrameTask:
    """One frame to render: its inputs, its lens and where its outputs go (absolute paths)."""

    index: int
    pair: FramePair
    lens: object
    output: str
    depth_output: str | None = None

    @property
    def outputs(self) -> tuple[str, ...]:
        return (self.output,) if self.depth_output is None else (self.output, self.depth_output)


def discard_outputs(task: FrameTask) -> None:
    """Remove *task*'s output files where they exist (an earlier run's, or this run's partial ones)."""
    for path in task.outputs:
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
        except OSError as err:
            raise ImageWriteError(f"cannot remove the earlier output {path}: {err.strerror or err}") from None


def outputs_complete(task: FrameTask) -> bool:
    # atomic writes: a file that exists under its final name is complete
    return all(os.path.isfile(p) for p in task.outputs)


def _stamp(path: str) -> list[int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return [int(st.st_size), int(st.st_mtime_ns)]


def input_stamps(pair: FramePair) -> dict:
    """What identifies the content of a frame's input files: ``{"color": [size, mtime_ns], "depth": ...}``.

    ``--resume`` keeps a frame only when its files still have the stamps recorded when it was rendered
    (a file rewritten in place changes its modification time, a different file its size or time).
    """
    return {"color": _stamp(pair.color), "depth": _stamp(pair.depth)}


def lens_fields(lens) -> dict:
    return {
        "focus_distance_m": float(lens.focus_distance_m),
        "f_number": float(lens.f_number) if isinstance(lens, ThinLens) else None,
        "focal_length_mm": float(lens.focal_length_mm) if isinstance(lens, ThinLens) else None,
    }


def base_record(task: FrameTask, output_dir: str, root: str | None = None) -> dict:
    """The report entry of *task* before it runs (paths relative to the input root / output folder)."""
    rel_in = (lambda p: os.path.relpath(p, root)) if root else (lambda p: p)
    return {
        "index": task.index,
        "key": task.pair.key,
        "color": rel_in(task.pair.color),
        "depth": rel_in(task.pair.depth),
        "color_time": task.pair.color_time,
        "depth_time": task.pair.depth_time,
        **({"frame": task.pair.frame} if task.pair.frame is not None else {}),
        "output": os.path.relpath(task.output, output_dir),
        "depth_output": os.path.relpath(task.depth_output, output_dir) if task.depth_output else None,
        "status": "pending",
        "skipped": None,
        "error": None,
        "seconds": 0.0,
        "cpu_seconds": 0.0,
        "stages": {},
        "skipped_stages": {},
        **lens_fields(task.lens),
        "worker": None,
    }


def failed_record(task: FrameTask, output_dir: str, error: str) -> dict:
    """The report entry of *task* when it failed outside :func:`~pcdof.batch.runner.render_frame` (its worker died)."""
    rec = base_record(task, output_dir)
    rec["status"], rec["error"] = "failed", error
    return rec
