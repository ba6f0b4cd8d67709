"""`pcdof demo`: render the bundled frames (no download needed) and show the effect side by side.

For every bundled real frame and the synthetic sample the demo

1. picks the main subject from the depth (:func:`pick_subject`: the nearest depth mode that fills at
   least 10 % of the central window, and the pixel deepest inside its connected region there),
2. focuses on it (the robust depth around that pixel, as ``pcdof render --focus-at`` does),
3. chooses a lens that blurs the background by at least 15 px per 640 px of image width
   (:func:`choose_lens`: f/1.4 and the shortest standard focal length that does it),
4. writes the physical render, the seed paper's method and ``<name>_side_by_side.png``
   (input | pcdof | paper method, with the lens and focus written on it).

The sample is also rendered with the lens its ray-traced ground truth was made for, and compared
with it (PSNR), into ``ground_truth_check/``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass

import click
import numpy as np

from ..errors import InputError
from ._common import handle_errors, make_output_folder
from ._report import is_quiet, report_decision

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))), "data")

#: name -> (folder under data/, colour, depth, calibration); Middlebury's im0 shares cam0 with depth0
FRAMES = {
    "tum": ("real/tum_rgbd_open3d", "color.png", "depth.png", "calib.json"),
    "nyu": ("real/nyu_v2_raw_open3d", "color.png", "depth.png", "calib.json"),
    "middlebury_adirondack": ("real/middlebury2014_evalQ/Adirondack", "im0.png", "depth0.png", "calib_im0.json"),
    "middlebury_motorcycle": ("real/middlebury2014_evalQ/Motorcycle", "im0.png", "depth0.png", "calib_im0.json"),
    "sample": ("sample", "color.png", "depth.png", "calib.json"),
}
#: standard focal lengths (mm) tried from short to long at :data:`F_NUMBER`
FOCAL_LENGTHS_MM = (35, 50, 85, 105, 135, 200, 300, 400, 500, 600, 800)
F_NUMBER = 1.4
#: the background blur the demo asks for: a circle-of-confusion diameter of 15 px per 640 px of image width
BACKGROUND_BLUR_PX = 15.0
BACKGROUND_BLUR_WIDTH_PX = 640
#: the depth percentile that stands for "the background"
BACKGROUND_PERCENTILE = 90.0


@dataclass(frozen=True)
class Subject:
    """The main subject: pixel (x, y) (column, row), its depth mode (metres) and how it was found."""

    x: int
    y: int
    mode_m: float
    share: float
    reason: str


def _depth_modes(depth_m: np.ndarray, *, bin_log: float, band_log: float) -> list[tuple[float, float]]:
    """Peaks of the log-depth histogram of *depth_m* (1-D, > 0): (depth m, share within +-band_log).

    The histogram is smoothed with a triangle over +-2 bins; each peak's depth is the mean log depth
    within +-2 bins of it (so a single depth comes out exactly).
    """
    lz = np.log(depth_m)
    edges = np.arange(lz.min() - 3 * bin_log, lz.max() + 4 * bin_log, bin_log)
    hist = np.convolve(np.histogram(lz, edges)[0], [1, 2, 3, 2, 1], "same").astype(np.float64)
    padded = np.concatenate([[-1.0], hist, [-1.0]])
    peaks = np.flatnonzero((hist > 0) & (hist > padded[:-2]) & (hist >= padded[2:]))
    modes = []
    for centre in 0.5 * (edges[peaks] + edges[peaks + 1]):
        near = lz[np.abs(lz - centre) <= 2.5 * bin_log]
        mode = float(near.mean()) if near.size else float(centre)
        modes.append((math.exp(mode), float(np.mean(np.abs(lz - mode) < band_log))))
    return modes


def _interior_pixel(mask: np.ndarray, window: tuple[slice, slice]) -> tuple[int, int, np.ndarray]:
    """(x, y, component): the pixel deepest inside the connected region of *mask* most present in *window*."""
    import cv2

    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    counts = np.bincount(labels[window].ravel(), minlength=labels.max() + 1)
    counts[0] = 0
    component = labels == int(np.argmax(counts))
    # distance to the nearest pixel outside the component (the image border counts as outside)
    inside = np.pad(component.astype(np.uint8), 1)
    dist = cv2.distanceTransform(inside, cv2.DIST_L2, 5)[1:-1, 1:-1]
    in_window = np.zeros_like(dist)
    in_window[window] = dist[window]
    y, x = np.unravel_index(int(np.argmax(in_window)), in_window.shape)
    return int(x), int(y), component


def pick_subject(depth_m, *, window: float = 0.5, min_share: float = 0.10, band: float = 0.08) -> Subject:
    """The main subject of a frame, from its depth alone.

    Rule: in the central window (the middle *window* of each side), take the histogram of log
    depth; its peaks are depth modes. The subject's depth is the nearest mode holding at least
    *min_share* of the window's known pixels (the largest mode when none does). The subject is the
    8-connected region of pixels within +-*band* (relative) of that depth that is most present in
    the window, and its pixel is the one inside the window farthest from the region's edge, so a
    focus window around it sees the subject only.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, registered to the colour camera, 0 or NaN = unknown
    window : float in (0, 1], side of the central window as a fraction of the image side
    min_share : float in (0, 1], smallest share of the window a mode needs to count as a subject
    band : float > 0, relative depth half-width of the subject's band (0.08 = +-8 %)

    Returns
    -------
    Subject
    """
    z = np.asarray(depth_m, dtype=np.float64)
    if z.ndim != 2 or min(z.shape) < 4:
        raise InputError(f"depth_m must be (H, W) with H, W >= 4; got shape {z.shape}")
    for name, value, ok in (("window", window, 0 < window <= 1), ("min_share", min_share, 0 < min_share <= 1),
                            ("band", band, band > 0)):
        if not (isinstance(value, (int, float)) and ok):
            raise InputError(f"{name} is out of range; got {value!r}")
    known = np.isfinite(z) & (z > 0)
    h, w = z.shape
    dy, dx = max(1, round(h * (1 - window) / 2)), max(1, round(w * (1 - window) / 2))
    win = (slice(dy, h - dy), slice(dx, w - dx))
    values = z[win][known[win]]
    if values.size == 0:
        raise InputError("depth_m has no known depth in the central window; cannot pick a subject")
    modes = _depth_modes(values, bin_log=band / 4, band_log=band)
    large = [m for m in modes if m[1] >= min_share]
    mode_m, share = min(large) if large else max(modes, key=lambda m: m[1])
    # the region: pixels within half the band, so its interior lies close to one depth
    mask = known & (np.abs(np.log(np.where(known, z, 1.0)) - math.log(mode_m)) < band / 2)
    x, y, _ = _interior_pixel(mask, win)
    how = "nearest" if large else f"largest (no mode reaches {min_share:.0%})"
    reason = (f"{how} depth mode near the centre, {mode_m:.2f} m ({share:.0%} of the central window); "
              f"pixel deepest inside its region")
    return Subject(x, y, mode_m, share, reason)


def choose_lens(depth_m, fx: float, focus_m: float, *, target_px: float = BACKGROUND_BLUR_PX):
    """The demo's lens: f/1.4 and the shortest standard focal length that blurs the background enough.

    The background is the 90th percentile of the known depth (the 10th when the subject is at the
    back); its blur is c = A * fx * |1/focus - 1/z_bg| with A = f / N (the README's lens model).
    Past the longest standard focal length, the one that gives exactly *target_px* (rounded up to 10 mm).

    Returns
    -------
    (ThinLens, z_bg metres, blur at z_bg in pixels)
    """
    from ..lens import ThinLens, positive_number

    fx = positive_number("fx", fx, InputError)
    focus_m = positive_number("focus_m", focus_m, InputError)
    target_px = positive_number("target_px", target_px, InputError)
    z = np.asarray(depth_m, dtype=np.float64)
    z = z[np.isfinite(z) & (z > 0)]
    if z.size == 0:
        raise InputError("depth_m has no known depth; cannot choose a lens")
    z_bg = float(np.percentile(z, BACKGROUND_PERCENTILE))
    if z_bg <= focus_m * 1.05:  # the subject is the background: blur what is in front instead
        z_bg = float(np.percentile(z, 100 - BACKGROUND_PERCENTILE))
    reach = fx * abs(1.0 / focus_m - 1.0 / z_bg)  # blur in px per metre of aperture
    if reach <= 0:
        raise InputError(f"the frame's depth has no range around the focus ({focus_m:.2f} m); nothing to blur")
    needed_mm = target_px / reach * F_NUMBER * 1e3
    focal_mm = next((f for f in FOCAL_LENGTHS_MM if f >= needed_mm), 10 * math.ceil(needed_mm / 10))
    lens = ThinLens(focal_length_mm=float(focal_mm), f_number=F_NUMBER, focus_distance_m=focus_m)
    return lens, z_bg, lens.aperture_m * reach


def side_by_side(panels, titles, caption: str, *, marker=None, panel_width: int = 640) -> np.ndarray:
    """Panels (each (H, W, 3) uint8 RGB) in a row, scaled to *panel_width*, titles above, a caption below.

    *marker* (x, y) in the first panel's pixels draws a cross there (the subject).
    """
    import cv2

    h0, w0 = panels[0].shape[:2]
    scale = panel_width / w0
    size = (panel_width, round(h0 * scale))
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_NEAREST  # never adds blur of its own
    tiles = []
    for i, (panel, title) in enumerate(zip(panels, titles)):
        tile = cv2.resize(np.ascontiguousarray(panel), size, interpolation=interp)
        if i == 0 and marker is not None:
            centre = (round(marker[0] * scale), round(marker[1] * scale))
            cv2.drawMarker(tile, centre, (0, 0, 0), cv2.MARKER_CROSS, 28, 5)
            cv2.drawMarker(tile, centre, (255, 255, 0), cv2.MARKER_CROSS, 26, 2)
        bar = np.zeros((34, size[0], 3), np.uint8)
        cv2.putText(bar, title, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.65, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(np.vstack([bar, tile]))
    row = np.hstack(tiles)
    lines = _wrap(caption, row.shape[1] // 11)
    foot = np.zeros((14 + 26 * len(lines), row.shape[1], 3), np.uint8)
    for k, line in enumerate(lines):
        cv2.putText(foot, line, (8, 28 + 26 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.65, (255, 255, 255), 1, cv2.LINE_AA)
    return np.vstack([row, foot])


def _wrap(text: str, width: int) -> list[str]:
    lines, line = [], ""
    for word in text.split():
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}".strip()
    return lines + [line]


def show_frame(name: str, frame, output: str) -> dict:
    """Subject, lens, physical and paper renders, and the side-by-side picture of one frame.

    Returns the frame's entry of ``summary.json`` (paths relative to *output*).
    """
    from .. import io, pipeline
    from ..focus import depth_at
    from ..lens import PaperLens, ThinLens

    registered, filled, _trace = pipeline.prepare_depth(frame, ThinLens(focal_length_mm=50.0, f_number=2.0,
                                                                        focus_distance_m=1.0))
    subject = pick_subject(filled)
    # the focus rule of `pcdof render --focus-at X,Y`: the median of the measured depth around the pixel
    focus_m = depth_at(registered, filled, subject.x, subject.y)
    fx = frame.rig.color.fx
    target_px = BACKGROUND_BLUR_PX * frame.rig.color.width / BACKGROUND_BLUR_WIDTH_PX
    lens, z_bg, bg_blur = choose_lens(filled, fx, focus_m, target_px=target_px)
    physical, _ = pipeline.render_from_depth(frame.color, filled, lens, fx, max_range_m=frame.rig.max_range_m)
    # the paper's method with its eq. 2 weight (sigma 0.3) and a Gaussian of the background disc's
    # standard deviation (a disc of diameter c has sigma c / 4 along each axis)
    paper_lens = PaperLens(focus_distance_m=focus_m, blur_sigma_px=max(bg_blur / 4, 0.5))
    paper, _ = pipeline.render_from_depth(frame.color, filled, paper_lens, fx, method="paper",
                                          max_range_m=frame.rig.max_range_m)
    max_blur = float(lens.coc_px(filled, fx).max())
    lens_text = f"{lens.focal_length_mm:g} mm f/{lens.f_number:g} (aperture {lens.aperture_m * 1e3:.0f} mm)"
    caption = (f"{name}: focus {focus_m:.2f} m on the subject at pixel ({subject.x}, {subject.y}) (cross), "
               f"{subject.reason}. Lens {lens_text}: background ({z_bg:.2f} m) blur {bg_blur:.1f} px, "
               f"largest blur {max_blur:.1f} px. Paper method: eq. 2 weight, Gaussian sigma "
               f"{paper_lens.blur_sigma_px:.1f} px.")
    picture = side_by_side([frame.color, physical, paper],
                           ["input", f"pcdof physical, {lens_text}", "paper method (seed paper, eq. 2)"],
                           caption, marker=(subject.x, subject.y))
    files = {"physical": f"{name}_physical.png", "paper": f"{name}_paper.png",
             "side_by_side": f"{name}_side_by_side.png"}
    for key, image in (("physical", physical), ("paper", paper), ("side_by_side", picture)):
        io.write_image(os.path.join(output, files[key]), image)
    report_decision("demo", output=os.path.join(output, files["side_by_side"]), focus_distance_m=focus_m,
                    focus_source=f"{name}'s subject at pixel ({subject.x}, {subject.y})", max_blur_px=max_blur,
                    details=f"{lens_text}, background {z_bg:.2f} m blurred {bg_blur:.1f} px")
    return {"subject": {"x": subject.x, "y": subject.y, "mode_m": subject.mode_m, "share": subject.share,
                        "rule": subject.reason},
            "focus_distance_m": focus_m, "focal_length_mm": lens.focal_length_mm, "f_number": lens.f_number,
            "background_m": z_bg, "background_blur_px": bg_blur, "max_blur_px": max_blur,
            "paper_blur_sigma_px": paper_lens.blur_sigma_px, "files": files}


def check_against_ground_truth(sample: str, output: str) -> None:
    """Render the sample with the lens of its ray-traced ground truth and print the PSNR of both methods."""
    from .. import io, pipeline
    from ..color import to_float
    from ..lens import ThinLens
    from ..metrics import psnr
    from .render import write_maps

    with open(os.path.join(sample, "lens.json")) as f:
        spec = json.load(f)
    lens = ThinLens(focal_length_mm=spec["focal_length_mm"], f_number=spec["f_number"],
                    focus_distance_m=spec["focus_distance_m"], aperture_blades=spec.get("aperture_blades", 0))
    frame = io.load_frame(*(os.path.join(sample, n) for n in ("color.png", "depth.png", "calib.json")))
    gt = to_float(io.read_color(os.path.join(sample, "dof_gt.png")))
    make_output_folder(output, "output")
    for method in ("physical", "paper"):
        result = pipeline.run(frame, lens, method=method)
        io.write_image(os.path.join(output, f"{method}.png"), result.image)
        if method == "physical":
            write_maps(os.path.join(output, "maps"), result)
        _echo(f"sample, {method}, the ground truth's lens ({lens.focal_length_mm:g} mm f/{lens.f_number:g} at "
              f"{lens.focus_distance_m:.2f} m): PSNR {psnr(to_float(result.image), gt):.2f} dB against the "
              f"ray-traced ground truth, {result.total_seconds * 1e3:.0f} ms")


def _echo(line: str) -> None:
    if not is_quiet():
        click.echo(line)


@click.command("demo")
@click.option("-o", "--output", default="out/demo", show_default=True, type=click.Path(readable=False))
@click.option("--data", "data_dir", default=DATA, show_default=False, type=click.Path(file_okay=False, readable=False),
              help="The repository's data folder.")
@click.option("--frame", "frames", type=click.Choice(list(FRAMES)), multiple=True,
              help="A frame to show (repeat the option for several; default: all).")
@handle_errors
def command(output, data_dir, frames):
    """Render the bundled frames (data/real and data/sample), focused on their subjects, side by side."""
    from .. import io, pipeline
    from ..lens import ThinLens

    make_output_folder(output, "output")
    names = [n for n in FRAMES if n in (frames or FRAMES)]
    loaded = {n: io.load_frame(*(os.path.join(data_dir, FRAMES[n][0], f) for f in FRAMES[n][1:])) for n in names}
    from ..runtime.kernels import ensure_warm

    ensure_warm()  # compiles (and says so) only on the first run after an install
    first = next(iter(loaded.values()))  # load every path's kernels before the timed renders
    warm_lens = ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=1.0)
    for method, lens in (("physical", warm_lens), ("paper", warm_lens)):
        pipeline.run(first, lens, method=method)
    summary = {name: show_frame(name, frame, output) for name, frame in loaded.items()}
    io.write_json(os.path.join(output, "summary.json"), summary)
    if "sample" in names:
        check_against_ground_truth(os.path.join(data_dir, FRAMES["sample"][0]), os.path.join(output, "ground_truth_check"))
    _echo(f"look at {os.path.join(output, '*_side_by_side.png')} (input | pcdof | paper method); "
          f"renders and {os.path.join(output, 'summary.json')} alongside")
