"""Write a synthetic frame (and optionally its depth-of-field ground truth) to a folder."""

from __future__ import annotations

import os

import numpy as np

from ..color import encode_from_linear
from ..errors import ImageWriteError, InputError
from ..io import write_depth, write_image, write_json
from ..lens import ThinLens
from .render import TARGET_PSNR_DB, check_samples, check_seed, max_coc_px, render_ground_truth

#: Every file :func:`write_scene` can write; a run removes those of them it did not write.
SCENE_FILES = ("color.png", "color_linear.npy", "depth.png", "depth_clean.npy", "depth_color_gt.npy", "calib.json",
               "lens.json", "dof_gt.png", "dof_gt_linear.npy", "scene.json")


def lens_to_dict(lens: ThinLens) -> dict:
    """The ``lens.json`` schema."""
    return {"focal_length_mm": lens.focal_length_mm, "f_number": lens.f_number,
            "focus_distance_m": lens.focus_distance_m, "aperture_blades": lens.aperture_blades,
            "aperture_rotation_deg": lens.aperture_rotation_deg}


def write_scene(synth_frame, outdir, *, lens: ThinLens | None = None, gt_samples: int | None = None,
                ground_truth: bool = True, linear: bool = True, gt_seed: int = 0,
                target_psnr_db: float = TARGET_PSNR_DB, progress: bool = False) -> dict:
    """Write a synthetic frame's files into *outdir* (each file atomically).

    Files: ``color.png`` (sRGB uint8), ``depth.png`` (16-bit millimetres, the sensor's noisy depth
    in the depth camera's grid, 0 = hole), ``depth_clean.npy`` (float32 metres, depth grid),
    ``depth_color_gt.npy`` (float32 metres, exact z-depth in the colour camera), ``calib.json``
    (``Rig.to_dict()`` plus ``max_range_m``), ``lens.json`` (*lens* or the scene's default lens),
    ``scene.json`` (name, seed, description, metadata, ground-truth settings); with *linear*:
    ``color_linear.npy`` (float32 linear radiance). With *lens* given, the ray-traced ground truth:
    ``dof_gt.png`` (sRGB uint8) and, with *linear*, ``dof_gt_linear.npy``.

    Once all of them are written, the files of :data:`SCENE_FILES` that this run did not write
    (left by an earlier run with other settings, e.g. ``dof_gt.png`` before ``ground_truth=False``)
    are removed, so the folder holds one consistent set; no other file is touched.

    Parameters
    ----------
    synth_frame : SyntheticFrame
    outdir : str or os.PathLike, created if missing
    lens : ThinLens or None, the lens of ``lens.json`` and of the ground truth (None = the scene's
        default lens, written to ``lens.json`` without rendering a ground truth)
    ground_truth : bool, render the ground truth when *lens* is given
    gt_samples : int or None, aperture samples per pixel (None = adaptive, until two independent
        half renders agree to *target_psnr_db*; see :func:`render_ground_truth`)
    linear : bool, also write the float32 linear-light images
    gt_seed : int, seed of the ground truth's aperture samples
    target_psnr_db : float, convergence target of the adaptive ground truth
    progress : bool, show progress bars while rendering the ground truth

    Returns
    -------
    dict: ``files`` (list of written paths) and ``ground_truth`` (a :class:`GroundTruth` without its
    image, as a dict; None without *lens*)
    """
    sf, with_gt = synth_frame, lens is not None and ground_truth
    _check_write_args(sf, lens, gt_samples if with_gt else None, gt_seed if with_gt else None)
    outdir = _make_folder(outdir)
    files = []

    def out(name):
        files.append(os.path.join(outdir, name))
        return files[-1]

    _write_frame(sf, lens if lens is not None else sf.default_lens, out, linear=linear)
    scene_info = {"name": sf.name, "seed": sf.seed, "description": sf.description, "metadata": sf.metadata,
                  "default_lens": lens_to_dict(sf.default_lens)}
    record = None
    if with_gt:
        record = _write_ground_truth(sf, lens, out, linear=linear, samples=gt_samples, seed=gt_seed,
                                     target_psnr_db=target_psnr_db, progress=progress)
        scene_info["ground_truth"] = record
    write_json(out("scene.json"), scene_info)
    _remove_stale(outdir, files)
    return {"files": files, "ground_truth": record}


def _check_write_args(synth_frame, lens, gt_samples, gt_seed) -> None:
    """InputError unless *synth_frame* is a SyntheticFrame, *lens* a ThinLens or None and the ground truth's
    settings (None where no ground truth is rendered) are valid: checked before any file is written."""
    if lens is not None and not isinstance(lens, ThinLens):
        raise InputError(f"lens must be a ThinLens or None; got {type(lens).__name__}")
    from .frame import SyntheticFrame

    if not isinstance(synth_frame, SyntheticFrame):
        raise InputError(f"synth_frame must be a SyntheticFrame; got {type(synth_frame).__name__}")
    if gt_samples is not None:
        check_samples(gt_samples, "gt_samples")
    if gt_seed is not None:
        check_seed(gt_seed, "gt_seed")


def _make_folder(outdir) -> str:
    """*outdir* as a str, created if missing (ImageWriteError when it cannot be)."""
    outdir = os.fspath(outdir)
    try:
        os.makedirs(outdir, exist_ok=True)
    except OSError as err:
        raise ImageWriteError(f"cannot create the output folder {outdir}: {err.strerror or err}") from None
    return outdir


def _write_frame(sf, lens: ThinLens, out, *, linear: bool) -> None:
    """The frame's colour, depths, calibration and *lens* (``lens.json``), each to the path ``out(name)``."""
    write_image(out("color.png"), sf.color)
    if linear:
        write_image(out("color_linear.npy"), sf.color_linear.astype(np.float32))
    write_depth(out("depth.png"), sf.depth_m)
    write_depth(out("depth_clean.npy"), sf.depth_clean_m)
    write_depth(out("depth_color_gt.npy"), sf.depth_color_m)
    write_json(out("calib.json"), {**sf.rig.to_dict(), "max_range_m": sf.rig.max_range_m})
    write_json(out("lens.json"), lens_to_dict(lens))


def _write_ground_truth(sf, lens: ThinLens, out, *, linear: bool, samples, seed: int, target_psnr_db: float,
                        progress: bool) -> dict:
    """Render the ray-traced ground truth through *lens*, write it to ``out(name)`` and return its record."""
    gt = render_ground_truth(sf, lens, samples=samples, seed=seed, target_psnr_db=target_psnr_db, progress=progress)
    write_image(out("dof_gt.png"), encode_from_linear(gt.image, np.uint8))
    if linear:
        write_image(out("dof_gt_linear.npy"), gt.image.astype(np.float32))
    return {"lens": lens_to_dict(lens), "samples_per_pixel": round(2 * gt.samples, 1),
            "max_samples_per_pixel": 2 * int(gt.counts.max()), "seed": seed,
            "half_render_psnr_db": round(gt.psnr_db, 3), "max_coc_px": round(max_coc_px(sf, lens), 3),
            "seconds": round(gt.seconds, 3)}


def _remove_stale(outdir: str, written: list) -> None:
    """Remove the files of :data:`SCENE_FILES` in *outdir* that are not in *written* (folders are left alone)."""
    for name in SCENE_FILES:
        path = os.path.join(outdir, name)
        if path in written or not os.path.lexists(path) or os.path.isdir(path):
            continue
        try:
            os.remove(path)
        except FileNotFoundError:
            pass
        except OSError as err:
            raise ImageWriteError(f"cannot remove the stale file {path} (from an earlier run): "
                                  f"{err.strerror or err}") from None
