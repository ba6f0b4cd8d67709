"""Blender's compositor as a peer: its Defocus node on pcdof's registered and filled depth.

An optional peer of the benchmarks, never a runtime dependency: the ``blender-defocus`` rows of ``pcdof bench``
appear when a Python interpreter with the ``bpy`` package from PyPI is at hand (:func:`blender_python`).
``bpy`` (4.2 to 5.0) requires numpy below 2 and pcdof's OpenCV numpy 2, so Blender runs in an environment of
its own: ``make blender`` makes one in ``.venv-blender``, and ``PCDOF_BLENDER_PYTHON`` names its interpreter.

The node gets what a compositor user would give it: the colour in linear light (the 8-bit frame decoded
from sRGB, as pcdof's renderer reads it) and a depth pass in metres, here pcdof's own registered and filled
depth, so that the rows compare the renderers and not the depth. Its camera is set so that the node's
circle of confusion is the thin lens's: Blender computes the diameter as
``(f / N) |v_z - v_f| / v_z`` metres on the sensor (Potmesil and Chakravarty 1981, eq. 8, with the image
distances ``v = f z / (z - f)``), which is ``(f / N) v_f |1/z_f - 1/z|``; with the sensor ``S`` and the focal
length ``f = fx S / W`` of the colour camera (so that its pixels per metre ``W / S`` times ``f`` is ``fx``)
and ``N = v_f / A``, that is ``A fx |1/z_f - 1/z|`` pixels, :meth:`pcdof.lens.ThinLens.coc_px` exactly.
The node's largest blur is set to the frame's largest CoC radius (the default, 16 px, would clip it; the
node's own bound, the CoC at infinity, would make it search thousands of pixels).

``bpy`` runs in a worker process (:class:`BlenderWorker`, :mod:`pcdof.bench.blender_worker`): it brings its own
libraries and numpy and prints a line per frame, which stay out of the benchmark's process.
"""

from __future__ import annotations

import atexit
import importlib.util
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np

from ..errors import InputError, PcdofError

#: the row name of the peer in the benchmark tables
NAME = "blender-defocus"
#: the environment variable naming the Python interpreter that has ``bpy``
PYTHON_VARIABLE = "PCDOF_BLENDER_PYTHON"
#: how to get one
INSTALL_HINT = "make blender makes one in .venv-blender (python3.11 -m venv .venv-blender; .venv-blender/bin/pip install bpy)"
#: the sensor width of the worker's camera, mm (any width gives the same CoC: the focal length follows it)
SENSOR_WIDTH_MM = 36.0
#: Blender's polygonal bokeh types by number of blades
BOKEH_TYPES = {0: "CIRCLE", 3: "TRIANGLE", 4: "SQUARE", 5: "PENTAGON", 6: "HEXAGON", 7: "HEPTAGON", 8: "OCTAGON"}


class BlenderError(PcdofError, RuntimeError):
    """Blender's compositor failed or is not installed."""


def available() -> bool:
    """True when an interpreter for Blender is configured or this one has ``bpy`` (:func:`blender_python`)."""
    return blender_python() is not None


def node_settings(*, width: int, fx: float, aperture_m: float, focus_distance_m: float) -> dict:
    """The camera and Defocus-node settings whose CoC is the thin lens's (see the module docstring).

    Parameters
    ----------
    width : the frame's width, pixels
    fx : the colour camera's focal length, pixels
    aperture_m : the lens's aperture diameter A, metres
    focus_distance_m : the focus distance z_f, metres

    Returns
    -------
    dict: ``sensor_width_mm``, ``focal_length_mm`` (the camera's) and ``f_stop`` (the node's)
    """
    for name, v in (("width", width), ("fx", fx), ("aperture_m", aperture_m), ("focus_distance_m", focus_distance_m)):
        if not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v) or v <= 0:
            raise InputError(f"{name} must be a finite number > 0; got {v!r}")
    f_mm = float(fx) * SENSOR_WIDTH_MM / float(width)
    f = f_mm * 1e-3
    if focus_distance_m <= f:
        raise InputError(f"focus_distance_m must exceed the camera's focal length {f:.4g} m; got {focus_distance_m!r}")
    v_f = f * focus_distance_m / (focus_distance_m - f)
    return {"sensor_width_mm": SENSOR_WIDTH_MM, "focal_length_mm": f_mm, "f_stop": v_f / float(aperture_m)}


def _bokeh(lens) -> tuple[str, float]:
    """The node's bokeh type and angle (radians) for *lens*'s aperture; BlenderError for shapes it has not."""
    if getattr(lens, "aperture_shape", None) is not None or lens.aperture_blades not in BOKEH_TYPES:
        raise BlenderError(f"Blender's Defocus node has a disc or 3 to 8 blades; the lens has "
                           f"{lens.aperture_shape or f'{lens.aperture_blades} blades'}")
    # the node's angle that draws pcdof's polygon: measured on a point source, the overlap of the two footprints
    # is largest at the same angle (hexagon: identical; pentagon 95 %, triangle 87 %, where Blender's kernel
    # differs in size)
    return BOKEH_TYPES[lens.aperture_blades], math.radians(lens.aperture_rotation_deg)


def blender_python() -> str | None:
    """The interpreter that runs Blender: ``$PCDOF_BLENDER_PYTHON``, else this one when it has ``bpy``, else None.

    ``bpy`` (4.2 to 5.0) pins numpy below 2, which pcdof's OpenCV does not accept, so it usually lives in an
    environment of its own (``make blender`` makes one in ``.venv-blender``) named by the variable."""
    configured = os.environ.get(PYTHON_VARIABLE, "").strip()
    if configured:
        return configured
    return sys.executable if importlib.util.find_spec("bpy") is not None else None


class BlenderWorker:
    """A process running ``bpy`` (:mod:`pcdof.bench.blender_worker`) that renders frames with the Defocus node
    (:meth:`defocus`); started on first use, by *python* (default :func:`blender_python`)."""

    def __init__(self, python: str | None = None):
        self.python = python
        self.version = None
        self._process = self._log = None

    def _start(self):
        python = self.python or blender_python()
        if python is None:
            raise BlenderError(f"Blender's compositor is not installed: set {PYTHON_VARIABLE} to a Python with bpy "
                               f"({INSTALL_HINT})")
        if not (os.path.isfile(python) and os.access(python, os.X_OK)):
            raise BlenderError(f"{PYTHON_VARIABLE} must name a Python interpreter; got {python!r}")
        self._log = tempfile.TemporaryFile()
        # -I: isolated, so that the worker's folder and PYTHONPATH shadow nothing
        self._process = subprocess.Popen([python, "-I", os.path.join(os.path.dirname(__file__), "blender_worker.py")],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                         bufsize=1)
        answer = self._receive()
        if "ready" not in answer:
            self.close()
            raise BlenderError(f"Blender's worker did not start: {answer.get('error')}")
        self.version = answer["ready"]

    def _receive(self) -> dict:
        line = self._process.stdout.readline()
        if not line:
            self._process.wait(timeout=10)
            self._log.seek(0)
            tail = self._log.read().decode("utf-8", "replace").strip().splitlines()[-3:]
            code = self._process.returncode
            self._process = None
            raise BlenderError(f"Blender's worker stopped (exit code {code}): {' / '.join(tail) or 'no message'}")
        return json.loads(line)

    def defocus(self, lin, depth_m, lens, *, fx: float, threads: int | None = None) -> tuple[np.ndarray, float]:
        """The Defocus node on one frame.

        Parameters
        ----------
        lin : (H, W, 3) float linear colour
        depth_m : (H, W) float depth, metres, > 0 everywhere (a filled depth)
        lens : :class:`pcdof.lens.ThinLens` (a disc or 3 to 8 blades)
        fx : the colour camera's focal length, pixels
        threads : the compositor's threads (None: every core)

        Returns
        -------
        ((H, W, 3) float32 linear image, seconds the compositor took)
        """
        lin = np.asarray(lin, np.float32)
        depth = np.asarray(depth_m, np.float32)
        if lin.ndim != 3 or lin.shape[2] != 3:
            raise InputError(f"lin must be (H, W, 3); got shape {lin.shape}")
        if depth.shape != lin.shape[:2]:
            raise InputError(f"depth_m must be (H, W) = {lin.shape[:2]}; got {depth.shape}")
        if not (np.isfinite(depth).all() and (depth > 0).all()):
            raise InputError("depth_m must be finite and > 0 everywhere (a filled depth)")
        bokeh, angle = _bokeh(lens)
        settings = node_settings(width=lin.shape[1], fx=fx, aperture_m=lens.aperture_m,
                                 focus_distance_m=lens.focus_distance_m)
        coc = lens.coc_px(depth, fx)
        settings.update(focus_distance_m=lens.focus_distance_m, bokeh=bokeh, angle=angle,
                        blur_max=float(math.ceil(float(coc.max()) / 2)) + 1.0, threads=int(threads or os.cpu_count()))
        if self._process is None:
            self._start()
        with tempfile.TemporaryDirectory(prefix="pcdof-blender-") as folder:
            np.save(os.path.join(folder, "lin.npy"), lin)
            np.save(os.path.join(folder, "depth.npy"), depth)
            try:
                self._process.stdin.write(json.dumps({"folder": folder, "settings": settings}) + "\n")
                self._process.stdin.flush()
            except OSError:
                pass  # the worker has stopped: _receive says how
            answer = self._receive()
            if "ok" not in answer:
                raise BlenderError(f"Blender's Defocus node failed: {answer.get('error')}")
            return np.load(os.path.join(folder, "out.npy")), float(answer["ok"])

    def close(self) -> None:
        """Stop the worker (a later :meth:`defocus` starts another)."""
        if self._process is not None:
            try:
                self._process.stdin.close()
            except OSError:
                pass
            try:
                self._process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
            self._process.stdout.close()
        if self._log is not None:
            self._log.close()
        self._process = self._log = None


_WORKER = BlenderWorker()
atexit.register(_WORKER.close)


def peer_note() -> str:
    """One line for a benchmark report: which Blender the ``blender-defocus`` rows ran, or how to add them."""
    if _WORKER.version:
        return (f"{NAME}: Blender {_WORKER.version}'s Defocus node (CPU compositor) on pcdof's registered and "
                f"filled depth, its circle of confusion the thin lens's.")
    if available():
        return f"{NAME}: Blender's Defocus node on pcdof's registered and filled depth (not run in this part)."
    return f"{NAME}: not run (no Python with bpy; set {PYTHON_VARIABLE}: {INSTALL_HINT})."


def render_blender(sf, lens) -> tuple[np.ndarray, dict[str, float]]:
    """The peer on a synthetic frame's measured input, as the benchmarks' methods run.

    pcdof registers and fills the depth (:func:`pcdof.pipeline.prepare_depth`); Blender's Defocus node
    renders the colour decoded to linear light; the result is encoded to the frame's dtype. Returns
    (image, seconds per stage: register, fill and render, the last the compositor's own time).
    """
    from ..color import decode_to_linear, encode_from_linear
    from ..pipeline import prepare_depth

    _registered, filled, trace = prepare_depth(sf.frame, lens)
    times = {t.name: t.seconds for t in trace}
    lin = decode_to_linear(sf.frame.color)
    out, times["render"] = _WORKER.defocus(lin, filled, lens, fx=sf.rig.color.fx)
    return encode_from_linear(out, sf.frame.color.dtype), times
