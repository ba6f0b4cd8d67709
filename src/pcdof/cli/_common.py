"""Shared CLI plumbing: logging set-up, one-line errors with distinct exit codes, common options, output checks.

Path options are plain ``click.Path()`` values: a folder given where a file belongs (or a file where a
folder belongs) is reported by pcdof's readers or by the checks below, as one of pcdof's errors with
its own exit code, not as a click usage error.
"""

from __future__ import annotations

import contextlib
import functools
import math
import logging
import os
import sys
import warnings

import click

from ..errors import EXIT_OUT_OF_MEMORY, ImageWriteError, InputError, PcdofError, exit_code_for, is_out_of_memory, \
    one_line

log = logging.getLogger("pcdof")


def configure_logging(verbose: int) -> None:
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="pcdof: %(message)s", stream=sys.stderr)

    def _showwarning(message, category, filename, lineno, file=None, line=None):
        click.echo(f"pcdof: warning: {one_line(message)}", err=True)

    warnings.showwarning = _showwarning


def handle_errors(func):
    """Turn any exception into one line on stderr and a non-zero exit code (tracebacks with -vv)."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        from .. import interrupts

        try:
            with interrupts.raising():  # Ctrl-C in the body unwinds it: its finally blocks clean up
                return func(*args, **kwargs)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except PcdofError as err:
            if _debug():
                raise
            click.echo(f"pcdof: error: {one_line(err)}", err=True)
            sys.exit(exit_code_for(err))
        except KeyboardInterrupt:
            if interrupts.installed():  # the console script: the line once, however the exit goes on
                interrupts.say_interrupted()
            else:
                click.echo("pcdof: interrupted", err=True)
            sys.exit(interrupts.EXIT_INTERRUPTED)
        except Exception as err:  # noqa: BLE001 - the CLI promises no tracebacks
            if is_out_of_memory(err):  # MemoryError, or OpenCV's "Insufficient memory"
                click.echo("pcdof: error: out of memory (try a smaller image)", err=True)
                sys.exit(EXIT_OUT_OF_MEMORY)
            if _debug():
                raise
            click.echo(f"pcdof: internal error: {type(err).__name__}: {one_line(err)} (run with -vv for details)",
                       err=True)
            sys.exit(1)

    return wrapper


def _debug() -> bool:
    ctx = click.get_current_context(silent=True)
    while ctx is not None:
        if ctx.obj and ctx.obj.get("verbose", 0) >= 2:
            return True
        ctx = ctx.parent
    return False



def check_output_file(path: str, name: str = "output") -> None:
    """ImageWriteError, before any work is done, when *path* cannot be written as a file.

    Refused: *path* is a folder, or the nearest existing one of its parent folders is not a folder.
    """
    if os.path.isdir(path):
        raise ImageWriteError(f"{name} {path!r} is a folder; expected a file name")
    _check_parents(path, name)


def check_output_folder(path: str, name: str) -> None:
    """ImageWriteError, before any work is done, when *path* cannot be (or become) a folder.

    Refused: *path* exists and is not a folder, or the nearest existing one of its parents is not a folder.
    """
    if os.path.lexists(path) and not os.path.isdir(path):
        raise ImageWriteError(f"{name} {path!r} is a file; expected a folder")
    _check_parents(path, name)


def make_output_folder(path: str, name: str) -> None:
    """Create the folder *path* (and its parents) if missing; ImageWriteError when it cannot be."""
    check_output_folder(path, name)
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise ImageWriteError(f"cannot create {name} folder {path!r}: {err.strerror or err}") from None


@contextlib.contextmanager
def all_or_nothing(files: list, folders: list = ()):
    """Within the block a command writes *files*; on any failure (Ctrl-C too) it leaves nothing behind.

    The files the block created (those that did not exist before it) are removed, then the *folders*
    it created, deepest first, if they are empty. A file that existed before is left as it is now
    (each file is written atomically, so it is either the old one or a complete new one).
    """
    from .. import interrupts

    existed = {path for path in files if os.path.lexists(path)}
    made = [folder for folder in folders if not os.path.lexists(folder)]

    def roll_back() -> None:
        for path in files:
            if path not in existed:
                with contextlib.suppress(OSError):
                    os.remove(path)
        for folder in sorted(made, key=len, reverse=True):
            with contextlib.suppress(OSError):
                os.rmdir(folder)  # only when empty

    with interrupts.cleanup_on_interrupt(roll_back):  # also when Ctrl-C ends the process at once
        try:
            yield
        except BaseException:
            roll_back()
            raise


def _check_parents(path: str, name: str) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    while not os.path.lexists(folder):  # ends at the root at the latest
        folder = os.path.dirname(folder)
    if not os.path.isdir(folder):
        raise ImageWriteError(f"cannot write {name} {path!r}: {folder!r} is not a folder")
    try:
        limit = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        limit = 255
    parts = os.path.relpath(os.path.abspath(path), folder).split(os.sep)
    for part in parts:  # the names still to be created
        if len(os.fsencode(part)) > limit:
            raise ImageWriteError(f"cannot write {name} {path!r}: File name too long ({len(os.fsencode(part))} "
                                  f"bytes; this file system allows {limit})")


def check_output_paths(inputs: dict, outputs: dict, folders: dict | None = None) -> None:
    """InputError, before any work, when an output would replace an input or another output.

    Every path is compared by :func:`pcdof.io._files.same_file`: symbolic links are resolved and
    hard links (same device and inode) are caught, so no spelling of an input's path can be written.

    Parameters
    ----------
    inputs : {label: path or None}, the files read (e.g. ``{"COLOR": ..., "DEPTH": ..., "--calib": ...}``)
    outputs : {label: path or None}, every file the command writes (a folder's files listed one by one)
    folders : {label: path or None}, output folders; no output file and no input may be one of them
    """
    from ..io._files import file_identity, fspath, same_file

    def named(mapping):
        return [(label, fspath(path, name=label)) for label, path in (mapping or {}).items() if path is not None]

    ins = [(label, path, file_identity(path)) for label, path in named(inputs)]
    outs = [(label, path, file_identity(path)) for label, path in named(outputs)]
    dirs = [(label, path, file_identity(path)) for label, path in named(folders)]
    for k, (label, path, ident) in enumerate(outs):
        for in_label, in_path, in_ident in ins:
            if same_file(ident, in_ident):
                raise InputError(f"refusing to overwrite the input {in_label} {in_path!r} with {label} {path!r}; "
                                 "choose another output path")
        for other_label, other_path, other_ident in outs[:k] + dirs:
            if same_file(ident, other_ident):
                raise InputError(f"{label} {path!r} and {other_label} {other_path!r} are the same path; give each "
                                 "output its own")
    for label, path, ident in dirs:
        for in_label, in_path, in_ident in ins:
            if same_file(ident, in_ident):
                raise InputError(f"{label} {path!r} is the input {in_label} {in_path!r}; choose another folder")


# ------------------------------------------------------------------------------------ frame sources
def source_arguments(func):
    """``INPUT [DEPTH]``, ``--calib``, ``--depth-scale``, ``--frame``, ``--time``: one frame from any source.

    INPUT is a colour image (then DEPTH and ``--calib`` go with it, as always), or alone a recording
    (``.mkv``, ``.bag``: calibration from the file, ``--calib`` overrides) or a sequence (a folder,
    TUM folder or list file), read through :func:`pcdof.sources.open_source`. Read the frame with
    :func:`load_source_frame`.
    """
    decorators = [
        click.argument("color", metavar="INPUT", type=click.Path(readable=False)),
        click.argument("depth", metavar="[DEPTH]", required=False, default=None, type=click.Path(readable=False)),
        click.option("--calib", type=click.Path(readable=False), default=None,
                     help="Calibration: calib.json, OpenCV .yml/.xml, or Open3D intrinsic JSON (needed with COLOR "
                          "DEPTH; a recording's own otherwise, a sequence's calib.json in its folder)."),
        click.option("--depth-scale", type=float, default=None,
                     help="Metres per depth unit (overrides the calibration; image files only)."),
        click.option("--frame", "frame_index", type=int, default=None,
                     help="With a recording or sequence INPUT: the frame index [default: 0; negative from the end]."),
        click.option("--time", "time_s", type=float, default=None,
                     help="With a recording or sequence INPUT: the frame nearest this time (seconds on its clock)."),
    ]
    for decorator in reversed(decorators):
        func = decorator(func)
    return func


def source_inputs(color, depth=None, calib=None) -> dict:
    """The input files the command line names, labelled for :func:`check_output_paths`."""
    if depth is not None:
        return {"COLOR": color, "DEPTH": depth, "--calib": calib}
    return {"INPUT": color, "--calib": calib}


def load_source_frame(color, depth=None, *, calib=None, depth_scale=None, frame_index=None, time_s=None,
                      outputs: dict | None = None, folders: dict | None = None):
    """The frame the command line names (see :func:`source_arguments`), outputs checked before it is read.

    Parameters
    ----------
    color : str, a colour image (with *depth*) or a recording / sequence path
    depth : str or None, the depth image of the colour image *color*
    calib : str or None, calibration file
    depth_scale : float or None, metres per depth unit
    frame_index, time_s : int or None, float or None, which frame of a recording or sequence
    outputs, folders : {label: path}, the command's outputs, refused when one is an input
        (:func:`check_output_paths`, run before any frame is read)

    Returns
    -------
    (RGBDFrame, str): the frame, and what it is (``"rec.bag frame 0 at 12.345 s"``; a phone photo's adds
    where its intrinsics come from) for messages
    """
    from ..io import load_frame
    from ..sources import open_source

    if depth is not None:
        if frame_index is not None or time_s is not None:
            raise InputError("--frame and --time choose a frame of a recording or sequence; COLOR DEPTH is one "
                             "frame (give INPUT alone)")
        if calib is None:
            raise click.UsageError("Missing option '--calib' (COLOR DEPTH needs a calibration)")
        check_output_paths(source_inputs(color, depth, calib), outputs or {}, folders)
        return load_frame(color, depth, calib, depth_scale=depth_scale), f"{color} + {depth}"
    if frame_index is not None and time_s is not None:
        raise InputError("--frame and --time exclude each other; give one")
    check_output_paths(source_inputs(color, None, calib), outputs or {}, folders)
    with open_source(color, calib=calib, depth_scale=depth_scale) as src:
        index = src.index_at(time_s) if time_s is not None else src.check_index(0 if frame_index is None
                                                                                   else frame_index)
        pairs = getattr(getattr(src, "sequence", None), "pairs", None)
        if pairs is not None:  # a sequence of image files: the frame's own files are inputs too
            check_output_paths({"COLOR": pairs[index].color, "DEPTH": pairs[index].depth}, outputs or {}, folders)
        frame = src.frame(index)
    when = f" at {frame.timestamp_s:.3f} s" if frame.timestamp_s is not None else ""
    camera = getattr(src, "camera_info", None)  # a phone photo: say where its intrinsics come from
    origin = f" (intrinsics from {camera['intrinsics_from']})" if camera else ""
    return frame.rgbd(), f"{color} frame {index}{when}{origin}"


# ------------------------------------------------------------------------------------ render options
def check_positive_flags(flags: dict, error=InputError, *, allow_zero: bool = False) -> None:
    """Refuse flag values that are not finite numbers > 0 (>= 0 with *allow_zero*; None = not given).

    *flags* maps flag names (``"--f-number"``) to their values; the error names the flag.
    """
    for flag, value in flags.items():
        if value is not None and not (math.isfinite(value) and (value >= 0 if allow_zero else value > 0)):
            raise error(f"{flag} must be a finite number {'>=' if allow_zero else '>'} 0; got {value}")


def _parse_xy(ctx, param, value):
    """Click callback: "X,Y" -> (float, float)."""
    if value is None:
        return None
    try:
        x, y = (float(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected X,Y in pixels (e.g. 320,240); got {value!r}") from None
    return x, y


def _render_option_decorators() -> list:
    from ..stages.fill import FILL_METHODS
    from ..stages.render import METHODS, QUALITIES

    return [
        click.option("--focal-length", "focal_length_mm", type=float, default=50.0, show_default=True,
                     help="Simulated focal length in mm (sets the aperture A = f/N)."),
        click.option("--f-number", type=float, default=1.8, show_default=True, help="Simulated f-number N."),
        click.option("--equivalent-f-number", "f_number_35mm", type=float, default=None, metavar="N",
                     help="The blur of a full-frame lens at f/N with the photo's own field of view (35 mm terms); "
                          "replaces --focal-length and --f-number. See docs/phone-photos.md."),
        click.option("--blur", "blur_percent", type=float, default=None, metavar="PERCENT",
                     help="A far background blurs into discs PERCENT of the image width wide (needs no metric "
                          "depth); replaces --focal-length and --f-number."),
        click.option("--focus-distance", "focus_distance_m", type=float, default=None,
                     help="Focus distance in metres (default: depth at the image centre)."),
        click.option("--focus-at", type=str, default=None, callback=_parse_xy, metavar="X,Y",
                     help="Focus at the robust depth around this colour pixel."),
        click.option("--aperture-blades", type=int, default=0, show_default=True,
                     help="0 = circular aperture; N >= 3 = polygon with N blades."),
        click.option("--aperture-rotation", "aperture_rotation_deg", type=float, default=0.0,
                     help="Rotation of the polygonal aperture in degrees."),
        click.option("--method", type=click.Choice(list(METHODS)), default="physical", show_default=True,
                     help="Rendering method."),
        click.option("--quality", type=click.Choice(list(QUALITIES)), default="balanced", show_default=True,
                     help="Physical method: speed/accuracy trade-off for large blur."),
        click.option("--fill-method", type=click.Choice(list(FILL_METHODS)), default="joint-bilateral",
                     show_default=True, help="Depth hole filling method."),
        click.option("--linear", is_flag=True, help="Colour is linear light (float EXR/TIFF/NPY), not sRGB."),
        click.option("--highlights", type=str, default="auto", show_default=True,
                     metavar="auto|off|gain|rim|prior|prior-rim|GAIN",
                     help="Physical method, 8/16-bit sRGB colour: estimate the radiance of clipped highlights "
                          "before the blur; only clipped channels are raised (auto: the level of least expected "
                          "error given each blob's blur; a number: that many times diffuse white)."),
        click.option("--sigma", "blur_sigma_px", type=float, default=4.0, show_default=True,
                     help="Paper method: Gaussian blur sigma in pixels."),
        click.option("--weight", type=click.Choice(["eq2", "eq1"]), default="eq2", show_default=True,
                     help="Paper method: blend weight (eq. 2 Gaussian or eq. 1 CoC)."),
        click.option("--weight-sigma", type=float, default=0.3, show_default=True,
                     help="Paper method: eq. 2 sigma on depth normalised by the sensor range."),
        click.option("--eq1-aperture", type=float, default=1.0, show_default=True,
                     help="Paper method with --weight eq1: the dimensionless A of C = A|d - d_f|/d "
                          "(weight = min(1, C))."),
    ]


#: the keyword names of the flags :func:`render_options` adds
RENDER_FLAG_NAMES = ("focal_length_mm", "f_number", "f_number_35mm", "blur_percent", "focus_distance_m", "focus_at", "aperture_blades",
                     "aperture_rotation_deg", "method", "quality", "fill_method", "linear", "highlights", "blur_sigma_px",
                     "weight", "weight_sigma", "eq1_aperture")


def render_options(func):
    """Add the render flags every rendering command shares; the command gets them as one dict, ``render_flags``.

    Turn them into the one :class:`~pcdof.options.RenderOptions` with :func:`build_render_options`
    (inside the command, so that a bad value is reported like any error).
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        flags = {name: kwargs.pop(name) for name in RENDER_FLAG_NAMES}
        return func(*args, render_flags=flags, **kwargs)

    for decorator in reversed(_render_option_decorators()):
        wrapper = decorator(wrapper)
    return wrapper


def device_option(func):
    """Add ``--device auto|cpu|gpu`` (:attr:`pcdof.options.RenderOptions.device`); the command gets ``device``
    and checks it with :func:`check_device` before reading any input."""
    from ..options import DEVICES

    return click.option("--device", type=click.Choice(list(DEVICES)), default="auto", show_default=True,
                        help="Where the stages run: gpu needs an NVIDIA GPU and `pip install pcdof[gpu]`; auto "
                             "uses the GPU when one is usable, else the CPU.")(func)


def check_device(device: str) -> str:
    """The device a command's frames run on ("cpu" or "gpu"); one line (DeviceError) for --device gpu without a
    usable GPU, saying why and how to install the extra."""
    from ..gpu.device import resolve_device

    return resolve_device(device)


def build_render_options(flags: dict, *, extra_positive: dict | None = None, thin_lens: bool = False):
    """The :class:`~pcdof.options.RenderOptions` of the flags of :func:`render_options`, every value checked.

    Parameters
    ----------
    flags : dict, ``render_flags`` as the command received it
    extra_positive : {flag: value}, more of the command's flags that must be finite numbers > 0
    thin_lens : bool, always a ThinLens (the viewer), also with ``--method paper``

    Returns
    -------
    RenderOptions; ``focus_at`` is "center" (:data:`pcdof.focus.CENTRE`) when no focus flag was given
    """
    from ..errors import LensError
    from ..focus import CENTRE
    from ..lens import PaperLens, ThinLens
    from ..options import RenderOptions

    f = flags
    if f["focus_distance_m"] is not None and f["focus_at"] is not None:
        raise InputError("--focus-distance and --focus-at exclude each other; give one")
    positive = {"--focus-distance": f["focus_distance_m"], "--focal-length": f["focal_length_mm"],
                "--f-number": f["f_number"], "--sigma": f["blur_sigma_px"], "--weight-sigma": f["weight_sigma"],
                "--eq1-aperture": f["eq1_aperture"], **(extra_positive or {})}
    check_positive_flags(positive, LensError)  # every lens flag is checked, whichever method uses it
    check_photo_lens_flags(f)
    provisional = f["focus_distance_m"] if f["focus_distance_m"] is not None else 1.0
    thin = ThinLens(focal_length_mm=f["focal_length_mm"], f_number=f["f_number"], focus_distance_m=provisional,
                    aperture_blades=f["aperture_blades"], aperture_rotation_deg=f["aperture_rotation_deg"])
    paper = PaperLens(focus_distance_m=provisional, sigma=f["weight_sigma"], blur_sigma_px=f["blur_sigma_px"],
                      weight=f["weight"], eq1_aperture=f["eq1_aperture"])
    lens = paper if f["method"] == "paper" and not thin_lens else thin
    return RenderOptions(lens=lens, method=f["method"], quality=f["quality"], fill_method=f["fill_method"],
                         linear=f["linear"], highlights=f["highlights"],
                         focus_at=CENTRE if f["focus_at"] is None and f["focus_distance_m"] is None else f["focus_at"])


def warn_float_colour(color, options) -> None:
    """Warn when float colour is read as sRGB: float files usually hold linear light (EXR, HDR TIFF)."""
    if getattr(color, "dtype", None) is not None and color.dtype.kind == "f" and not options.linear:
        warnings.warn("the colour image holds floats and is read as sRGB in [0, 1]; "
                      "pass --linear if it holds linear light (EXR, float TIFF/NPY from a renderer or raw converter)")


def focus_source(flags: dict) -> str:
    """How the focus was chosen, for the command's report line."""
    if flags["focus_distance_m"] is not None:
        return "--focus-distance"
    if flags["focus_at"] is not None:
        x, y = flags["focus_at"]
        return f"--focus-at {x:g},{y:g}"
    return "depth at the image centre"




def check_photo_lens_flags(flags: dict) -> None:
    """LensError for ``--equivalent-f-number`` / ``--blur`` values that no lens has, or given together."""
    from ..errors import LensError

    n, blur = flags.get("f_number_35mm"), flags.get("blur_percent")
    check_positive_flags({"--equivalent-f-number": n, "--blur": blur}, LensError)
    if n is not None and blur is not None:
        raise InputError("--equivalent-f-number and --blur exclude each other; give one")
    if blur is not None and blur > 100:
        raise LensError(f"--blur is a percentage of the image width, at most 100; got {blur:g}")
    if (n is not None or blur is not None) and flags.get("method") == "paper":
        raise InputError("--equivalent-f-number and --blur set a thin lens; the paper method has none")


def photo_lens(options, flags: dict, rig):
    """*options* with the lens ``--equivalent-f-number`` or ``--blur`` asks for, for *rig*'s colour camera."""
    from ..phone_lens import BlurShareLens, equivalent_lens

    if flags.get("f_number_35mm") is not None:
        return options.replace(lens=equivalent_lens(options.lens, rig.color, flags["f_number_35mm"]))
    if flags.get("blur_percent") is not None:
        return options.replace(lens=BlurShareLens.for_camera(options.lens, rig.color, flags["blur_percent"] / 100))
    return options
