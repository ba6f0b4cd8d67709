"""The per-frame pipeline on the GPU: register -> fill -> circle of confusion -> highlights -> render.

The stages' decisions (skip, and why) are those of :mod:`pcdof.pipeline`; what runs where:

- on the device: colour decoding, registration, the ``joint-bilateral`` and ``nearest-background`` fills,
  the thin-lens circle of confusion, the physical render with its layers and compositing, the encoding;
- on the host: the highlights stage's reconstruction (only for 8/16-bit sRGB frames with clipped pixels and
  highlights on), the ``telea`` fill (OpenCV) and the paper method's render (a Gaussian blend, cheap on the CPU).

This module returns plain parts (arrays and trace records as dicts); :func:`pcdof.pipeline.run` wraps them in
its :class:`~pcdof.pipeline.RenderResult`, so the two paths give one result type.
"""

from __future__ import annotations

import time

import numpy as np

from ..camera import RGBDFrame
from ..errors import InputError
from ..focus import resolve_lens
from ..lens import ThinLens, aperture_for
from ..stages.render import SHARP_COC_PX
from ..stages.render.border import border_px
from ..stages.render.classify import frame_edges
from .coc import coc_maps
from .color import decode, encode
from .fill import count_holes, fill_depth
from .launch import on_device, thread_stream, to_device
from .register import register_depth
from .render import clamped_window, continued_border, mix_edges, render_layers_linear


class _Stage:
    """Times one stage (synchronising *stream* at its end when *sync*) and records it as a dict."""

    def __init__(self, trace: list, name: str, stream, sync: bool):
        self.trace, self.name, self.stream, self.sync = trace, name, stream, sync

    def __enter__(self):
        self.t0 = time.perf_counter()
        self.rec = {"name": self.name, "seconds": 0.0, "skipped": False, "reason": "", "detail": {"device": "gpu"}}
        return self.rec

    def __exit__(self, *exc):
        if self.sync and exc[0] is None:
            self.stream.synchronize()
        self.rec["seconds"] = time.perf_counter() - self.t0
        self.trace.append(self.rec)
        return False


def _register(frame: RGBDFrame, depth_dev, trace, stream, sync):
    from ..stages.register import needs_registration, open_coarse_edges
    from ..stages.register.guided import coarse_depth_scale

    with _Stage(trace, "register", stream, sync) as rec:
        needed, reason = needs_registration(frame.rig)
        rec["reason"] = reason
        if not needed:
            rec["skipped"] = True
            return depth_dev
        registered = register_depth(depth_dev, frame.rig, stream=stream)
        if coarse_depth_scale(frame.rig) is None:
            return registered
        # a phone's coarse depth grid: its edges are opened on the host, as the CPU's register stage does, and
        # the fill redraws them where the colour changes
        opened, edges = open_coarse_edges(registered.copy_to_host(stream=stream), frame.rig)
        rec["reason"] += f"; {edges['opened']} px at depth edges left to the colour-guided fill"
        rec["detail"]["edges"] = edges
        return to_device(opened, stream=stream)


def _fill(registered, frame: RGBDFrame, color_dev, opts, trace, stream, sync):
    """Filled depth on the device, and the registered depth's number of holes."""
    from ..stages.fill import fill_depth as cpu_fill

    with _Stage(trace, "fill", stream, sync) as rec:
        if opts.fill_method == "joint-bilateral":
            # measured depth edges moved onto the colour edges on the host, as the CPU's fill stage does
            from ..stages.fill import align_depth_edges

            aligned, moved = align_depth_edges(registered.copy_to_host(stream=stream), frame.color, with_count=True)
            rec["detail"]["edges_moved"] = moved
            if moved:
                registered = to_device(aligned, stream=stream)
        prepared = count_holes(registered, stream)
        holes = int(prepared[2].copy_to_host(stream=stream)[0])
        rec["detail"]["holes"] = holes
        if holes == 0:
            rec["skipped"], rec["reason"] = True, "no holes"
            return prepared[0]
        if holes == registered.size:
            raise InputError("depth has no known pixel: nothing to fill from")
        rec["reason"] = f"{holes} holes ({opts.fill_method})"
        if opts.fill_method == "telea":  # OpenCV's inpainting: on the CPU
            rec["detail"]["device"] = "cpu"
            host = registered.copy_to_host(stream=stream)
            return to_device(cpu_fill(host, frame.color, method=opts.fill_method), stream)
        guide = decode(color_dev, linear=True, stream=stream)
        return fill_depth(registered, guide, use_color=opts.fill_method == "joint-bilateral", prepared=prepared,
                          stream=stream)


def _highlights(color, opts, coc_size, cmax, trace):
    """(linear float32 host colour or None, whether it was reconstructed): the CPU's highlights stage."""
    from ..stages.highlights import needs_reconstruction, parse_highlights, prepare_highlights, reconstruct_prepared

    t0 = time.perf_counter()
    rec = {"name": "highlights", "seconds": 0.0, "skipped": True, "reason": "", "detail": {"device": "cpu"}}
    how, gain = parse_highlights(opts.highlights)
    found = None
    if how == "off":
        rec["reason"] = "off"
    elif opts.method != "physical" or coc_size is None:
        rec["reason"] = "the paper method blends as written"
    elif not needs_reconstruction(color, linear=opts.linear):
        rec["reason"] = "linear input is not clipped"
    elif cmax < SHARP_COC_PX:
        rec["reason"] = f"nothing to blur (largest circle of confusion {cmax:.3f} px < {SHARP_COC_PX} px)"
    else:
        found = prepare_highlights(color)
        if found is None:
            rec["reason"] = "nothing clipped"
    out = None
    if found is not None:
        out = reconstruct_prepared(found, method=how, gain=gain, coc_px=coc_size.copy_to_host())
        rec["skipped"] = False
        rec["reason"] = f"{how}: {found.clipped_pixels} clipped pixels"
    rec["seconds"] = time.perf_counter() - t0
    trace.append(rec)
    return out


def _render_physical(frame, color_dev, depth, opts, lens, signed, cmax, source_linear, trace, stream, sync):
    """Device image of the input's dtype, or None when nothing is blurred (the input is the output); *depth* the
    filled depth the CoC was computed from (device)."""
    with _Stage(trace, "render", stream, sync) as rec:
        if cmax < SHARP_COC_PX:
            rec["skipped"] = True
            rec["reason"] = f"largest circle of confusion {cmax:.3f} px < {SHARP_COC_PX} px: nothing to blur"
            return None
        if source_linear is not None:
            lin = to_device(np.ascontiguousarray(source_linear, np.float32), stream)
        else:
            lin = decode(color_dev, linear=opts.linear, stream=stream)
        # what lies beyond the frame is continued from its edge: rendered widened, then cut back
        h, w = frame.color.shape[:2]
        pad = border_px(cmax)
        wide = (h + 2 * pad, w + 2 * pad)
        # light above white estimated by the highlights stage is not continued beyond the frame
        most = 1.0 if source_linear is not None else None
        # the layer edges of the frame's own CoC, as the CPU renderer takes them (not of its widened copy)
        edges = frame_edges(signed.copy_to_host(stream=stream) if on_device(signed) else np.asarray(signed))
        wide_lin = continued_border(lin, pad, most, stream)
        out_lin, layers = render_layers_linear(wide_lin, clamped_window(signed, -pad, -pad, wide, stream),
                                               aperture_for(lens), stream=stream, edges=edges)
        out_lin = clamped_window(out_lin, pad, pad, (h, w), stream)
        # an in-focus structure's edge pixels that carry the depth behind it (pcdof.stages.render.mixed)
        mix_edges(out_lin, wide_lin, depth, signed, pad, stream)
        blurred = [l for l in layers if l["key"] != 0]
        rec["reason"] = f"physical, {len(blurred)} blur layers, exact scatter at full resolution"
        rec["detail"]["layers"] = layers
        linear_out = opts.linear and source_linear is None
        return encode(out_lin, frame.color.dtype, linear=linear_out, stream=stream)


def run_stages(frame: RGBDFrame, opts, *, stream=None, sync: bool = True) -> dict:
    """Run every stage of *frame* under :class:`~pcdof.options.RenderOptions` *opts* on the GPU.

    Parameters
    ----------
    frame : RGBDFrame
    opts : RenderOptions (its ``device`` is not read: the caller chose this path)
    stream : a CUDA stream, or None for this thread's (:func:`pcdof.gpu.launch.thread_stream`)
    sync : synchronise the stream at the end of each stage, so that the trace's seconds are the stage's

    Returns
    -------
    dict: image (host, the input colour's dtype and shape), depth_registered_m, depth_filled_m (host (H, W)
    float32), coc_px (host (H, W) float32 or None), lens, trace (list of dicts: name, seconds, skipped, reason,
    detail)
    """
    if not isinstance(frame, RGBDFrame):
        raise InputError(f"frame must be an RGBDFrame; got {type(frame).__name__}")
    stream = thread_stream() if stream is None else stream
    trace: list = []
    with _Stage(trace, "upload", stream, sync) as rec:
        depth_dev = to_device(np.asarray(frame.depth_m, np.float32), stream)
        color = frame.color if frame.color.ndim == 3 else frame.color[:, :, None]
        color_dev = color if color.dtype.kind == "f" else to_device(color, stream)  # floats decode on the host
        rec["reason"] = "depth and colour to the device"
    registered = _register(frame, depth_dev, trace, stream, sync)
    filled = _fill(registered, frame, color_dev, opts, trace, stream, sync)
    registered_host = registered.copy_to_host(stream=stream)
    filled_host = filled.copy_to_host(stream=stream)
    lens = resolve_lens(opts.lens, opts.focus_at, registered_host, filled_host)
    coc_host = signed = size = None
    cmax = 0.0
    if isinstance(lens, ThinLens):
        with _Stage(trace, "coc", stream, sync) as rec:
            signed, size, stats = coc_maps(filled, lens, frame.rig.color.fx, stream=stream)
            cmax = float(stats.copy_to_host(stream=stream)[0])
            rec["reason"] = f"max {cmax:.2f} px"
            rec["detail"]["max_coc_px"] = cmax
    source_linear = _highlights(frame.color, opts, size, cmax, trace)
    if opts.method == "physical":
        image_dev = _render_physical(frame, color_dev, filled, opts, lens, signed, cmax, source_linear, trace, stream,
                                     sync)
    else:
        image_dev = None
        _render_paper_on_host(frame, opts, lens, filled_host, trace)
    with _Stage(trace, "download", stream, sync) as rec:
        if image_dev is not None:
            image = image_dev.copy_to_host(stream=stream).reshape(frame.color.shape)
        elif opts.method == "physical":
            image = frame.color.copy()
        else:
            image = trace[-1]["detail"].pop("image")
        coc_host = size.copy_to_host(stream=stream) if signed is not None else None
        stream.synchronize()
        rec["reason"] = "image and depth maps to the host"
    return {"image": image, "depth_registered_m": registered_host, "depth_filled_m": filled_host, "coc_px": coc_host,
            "lens": lens, "trace": trace}


def _render_paper_on_host(frame, opts, lens, filled_host, trace) -> None:
    """The paper method's render on the CPU (its image parked in the record's detail until the download)."""
    from ..stages.render import render_image

    t0 = time.perf_counter()
    image, info = render_image(frame.color, filled_host, lens, fx=frame.rig.color.fx, method="paper",
                               max_range_m=frame.rig.max_range_m, linear=opts.linear, quality=opts.quality)
    trace.append({"name": "render", "seconds": time.perf_counter() - t0, "skipped": bool(info.get("skipped", False)),
                  "reason": str(info.get("reason", "paper")) + " (on the CPU)", "detail": {"device": "cpu",
                                                                                        "image": image}})
