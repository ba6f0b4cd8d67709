"""The circle-of-confusion stage: the lens focused as the options say (:mod:`pcdof.focus`), then the thin-lens
circle of confusion of every pixel (:meth:`pcdof.lens.ThinLens.coc_maps_px`), computed once for the
highlights and the renderer. Its plain reference is :mod:`.reference`."""

from .stage import CocStage

__all__ = ["CocStage"]
