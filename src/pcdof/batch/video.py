"""The batch's video: its frames encoded as H.264 (yuv420p), written atomically."""

from __future__ import annotations

import logging
import os
import uuid

import numpy as np

from ..color import to_uint8
from ..errors import ImageWriteError, InputError, PcdofError

log = logging.getLogger("pcdof.batch")


def _even_pad(image: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    ph, pw = h % 2, w % 2
    if ph or pw:  # yuv420p needs even sides: repeat the last row / column
        image = np.pad(image, ((0, ph), (0, pw), (0, 0)), mode="edge")
    return image


def _to_rgb8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) or (H, W) image -> contiguous (H, W, 3) uint8 RGB (:func:`pcdof.color.to_uint8`)."""
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    return np.ascontiguousarray(to_uint8(image))


def _open_writer(tmp: str, size: tuple[int, int], fps: float, quality: float):
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(tmp, size, fps=fps, codec="libx264", pix_fmt_in="rgb24",
                                         pix_fmt_out="yuv420p", quality=quality, macro_block_size=2,
                                         ffmpeg_log_level="error")
    writer.send(None)
    return writer


def write_video(images, path: str, *, fps: float = 30.0, quality: float = 8.0) -> dict:
    """Encode RGB frames into an H.264 (libx264, yuv420p) video, atomically.

    Parameters
    ----------
    images : iterable of (H, W, 3) ndarray (uint8, uint16 or float in [0, 1]), all the same size;
        odd sides are padded by one repeated row / column (yuv420p needs even sides)
    path : str, .mp4 / .m4v / .mov / .mkv
    fps : float, frames per second
    quality : float, imageio-ffmpeg quality 0-10 (10 = best)

    Returns
    -------
    dict with path, frames, width, height, fps
    """
    path = os.path.abspath(os.fspath(path))
    folder, base = os.path.split(path)
    stem, ext = os.path.splitext(base)
    tmp = os.path.join(folder, f".{stem}.{uuid.uuid4().hex[:8]}.partial{ext}")
    writer = None
    n, size = 0, None
    try:
        os.makedirs(folder, exist_ok=True)
        for image in images:
            frame = _even_pad(_to_rgb8(np.asarray(image)))
            if size is None:
                size = (frame.shape[1], frame.shape[0])
                writer = _open_writer(tmp, size, fps, quality)
            elif (frame.shape[1], frame.shape[0]) != size:
                raise InputError(f"video frames must all be {size[0]}x{size[1]}; frame {n} is "
                                 f"{frame.shape[1]}x{frame.shape[0]}")
            writer.send(frame)
            n += 1
        if writer is None:
            raise InputError("no frames to write into the video")
        writer.close()
        writer = None
        os.replace(tmp, path)
    except (OSError, RuntimeError) as err:
        raise ImageWriteError(f"cannot write video {path}: {err}") from None
    finally:
        if writer is not None:
            try:
                writer.close()
            except Exception:  # noqa: BLE001 - already failing
                pass
        if os.path.exists(tmp):
            os.unlink(tmp)
    return {"path": path, "frames": n, "width": size[0], "height": size[1], "fps": fps}


def make_video(records: list[dict], output_dir: str, video: str, fps: float) -> dict:
    """Video of the batch's frames in order, one video frame per frame.

    A frame that failed repeats the previous good one; failed frames before the first good one show
    the first good one. ``held_frames`` lists those frames, ``held_from`` pairs each with the frame shown.
    """
    from .. import io

    paths = [os.path.join(output_dir, rec["output"]) for rec in records]
    good = [rec["status"] in ("ok", "skipped") and os.path.isfile(p) for rec, p in zip(records, paths)]
    shown, last = [], good.index(True) if any(good) else None  # the first good frame stands in at the start
    for k, g in enumerate(good):
        last = k if g else last
        shown.append(last)
    held = [[records[k]["index"], records[s]["index"]] for k, s in enumerate(shown) if not good[k] and s is not None]

    def frames():
        image, loaded = None, None
        for s in shown:
            if s is None:  # no good frame at all: write_video reports "no frames"
                return
            if s != loaded:
                image, loaded = io.read_color(paths[s]), s
            yield image

    try:
        info = write_video(frames(), video, fps=fps)
    except PcdofError as err:
        log.warning("video not written: %s", err)
        return {"path": os.path.abspath(video), "error": f"{type(err).__name__}: {err}"}
    info["held_frames"] = [k for k, _ in held]
    info["held_from"] = held
    return info
