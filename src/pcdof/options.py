"""One object for everything that decides how a frame is rendered.

:class:`RenderOptions` is built once at the boundary (the CLI parses its flags into one; a Python
caller builds one by keyword) and passed whole to :func:`pcdof.pipeline.run`, the viewer, the batch
runner and the benchmark. It is frozen: change a field with :meth:`RenderOptions.replace` (or
``dataclasses.replace``), which checks the new value like the constructor does. A new option is a
new field here, with its check, and the stage that reads it; no signature in between changes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .validate import short_repr
from .errors import InputError, LensError
from .focus import parse_focus_at
from .lens import PaperLens, ThinLens

#: Ways to run the per-frame pipeline: "cpu", "gpu" (the optional CUDA backend, :mod:`pcdof.gpu`; needs
#: ``pip install pcdof[gpu]`` and a GPU) or "auto" (the GPU when a usable one is found, else the CPU).
DEVICES = ("auto", "cpu", "gpu")


@dataclass(frozen=True)
class RenderOptions:
    """How to render a frame: the lens and every choice the pipeline makes.

    Parameters
    ----------
    lens : ThinLens (physical or paper method) or PaperLens (paper method only)
    method : a key of :data:`pcdof.stages.render.METHODS` ("physical", "paper")
    quality : physical method's speed/accuracy tier, a key of :data:`pcdof.stages.render.QUALITIES`
    fill_method : depth hole filling, a key of :data:`pcdof.stages.fill.FILL_METHODS`
    linear : colour holds linear light (float, may exceed 1) instead of sRGB
    focus_at : None (the lens's focus distance), an (x, y) colour pixel or "center" (the image centre): the
        focus distance becomes the robust depth there (:mod:`pcdof.focus`)
    highlights : radiance of clipped highlights before the blur (physical method, 8/16-bit sRGB input
        only; linear input is never touched): a key of :data:`pcdof.stages.highlights.HIGHLIGHT_METHODS`
        ("auto", the default: each clipped channel raised to the level of least expected error under a
        stated prior, chosen on the wide benchmark's tuning seeds; "off", "gain", "rim", "prior",
        "prior-rim") or a gain >= 1. Only clipped channels are raised, so every output pixel stays
        within the input's per-channel range
    device : where the pipeline runs, one of :data:`DEVICES`
    """

    lens: ThinLens | PaperLens
    method: str = "physical"
    quality: str = "balanced"
    fill_method: str = "joint-bilateral"
    linear: bool = False
    focus_at: tuple[float, float] | str | None = None
    highlights: str | float = "auto"
    device: str = "auto"

    def __post_init__(self) -> None:
        from .stages.fill import check_fill_method
        from .stages.render import check_method, check_quality

        if not isinstance(self.lens, (ThinLens, PaperLens)):
            raise LensError(f"lens must be a ThinLens or PaperLens; got {type(self.lens).__name__}")
        check_method(self.method)
        if self.method == "physical" and isinstance(self.lens, PaperLens):
            raise LensError("the physical method needs a ThinLens; a PaperLens only works with method='paper'")
        check_quality(self.quality)
        check_fill_method(self.fill_method, "fill_method")
        if not isinstance(self.linear, bool):
            raise InputError(f"linear must be True or False; got {short_repr(self.linear)}")
        object.__setattr__(self, "focus_at", parse_focus_at(self.focus_at))
        from .stages.highlights import HIGHLIGHT_METHODS, parse_highlights

        _, gain = parse_highlights(self.highlights)  # a method's name stays a name; a number becomes a float
        if not (isinstance(self.highlights, str) and self.highlights in HIGHLIGHT_METHODS):
            object.__setattr__(self, "highlights", gain)
        if not isinstance(self.device, str) or self.device not in DEVICES:
            raise InputError(f"device must be one of {list(DEVICES)}; got {short_repr(self.device)}")

    def replace(self, **changes) -> "RenderOptions":
        """A copy with *changes* applied (checked like the constructor)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """Plain JSON-ready description (reports, resume keys)."""
        out = dataclasses.asdict(self)
        out["lens"] = {"type": type(self.lens).__name__, **dataclasses.asdict(self.lens)}
        out["focus_at"] = list(self.focus_at) if isinstance(self.focus_at, tuple) else self.focus_at
        return out


def as_options(lens_or_options, **overrides) -> RenderOptions:
    """*lens_or_options* as a :class:`RenderOptions`: a lens plus keyword options, or options (with
    *overrides* applied). The one place the pipeline's entry points accept either form."""
    if isinstance(lens_or_options, RenderOptions):
        return lens_or_options.replace(**overrides) if overrides else lens_or_options
    fields = {f.name for f in dataclasses.fields(RenderOptions)} - {"lens"}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise InputError(f"unknown render option {unknown[0]!r}; expected one of {sorted(fields)}")
    return RenderOptions(lens_or_options, **overrides)
