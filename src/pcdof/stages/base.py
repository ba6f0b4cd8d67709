"""The stage contract: every stage of the pipeline (register, fill, coc, highlights, render) is one object with

* ``name``: how the trace calls it;
* ``skip(state, options) -> str | None``: why there is nothing to do for this frame (None: there is);
* ``passthrough(state, options) -> dict``: the stage's outputs when it is skipped (e.g. the depth unchanged);
* ``plan(state, options) -> plan | None``: how to run (threads, tiles, kernels), a frozen dataclass recorded in
  the trace; every plan a stage accepts gives its reference's answer within the tolerance the plan states;
* ``run(state, plan, options) -> StageOutput``: the work, returning new fields of the state and what to say.

Stages read and write :class:`FrameState`, plain data: arrays and the lens. The pipeline
(:mod:`pcdof.pipeline`) runs them in order under the runtime's thread settings and times each; a stage never
sets threads, starts pools or compiles ahead (:mod:`pcdof.runtime` does). Adding a stage is a class with
these methods and an entry in :data:`pcdof.stages.STAGES` (or a ``stages=`` list passed to
:func:`pcdof.pipeline.run_stages`).

A stage may also start part of its work early, beside an earlier stage (the highlights stage reads the colour
while the fill runs; the render stage classifies the frame into layers while the highlights stage runs):
``starts_before`` names that stage and ``start(state, options)`` returns a function that waits for the result (or
None when the frame does not need it); the pipeline calls ``start`` just before the named stage runs and passes the
waiter to ``run`` through ``state.started``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class FrameState:
    """What the stages pass each other (fields are None until the stage that makes them has run).

    Attributes
    ----------
    color : (H, W[, C]) colour as given (uint8/uint16 sRGB or float)
    depth_m : (h, w) float32 metres of the depth camera, 0 = unknown
    rig : :class:`pcdof.camera.Rig`, the calibration (None when the stages start from registered depth)
    fx_px : float, the colour camera's focal length, pixels
    max_range_m : float, the depth sensor's range, metres (the paper method's eq. 2)
    registered_m : (H, W) float32 metres on the colour grid, 0 = unknown (register)
    filled_m : (H, W) float32 metres, no holes (fill)
    lens : the lens with its focus resolved (coc; :mod:`pcdof.focus`)
    signed_coc_px : (H, W) float32 circle of confusion, pixels, negative in front of focus (coc; None for the
        paper method); its size is ``abs(signed_coc_px)`` (the result's ``coc_px``, derived once the stages ran)
    coc_max_px : float, the largest size (coc)
    source, source_linear : the colour the renderer blurs and whether it is linear light (highlights)
    source_border_px : int, how far *source* reaches beyond the frame on every side (highlights: the estimated
        radiance comes widened by the render's border, :func:`pcdof.stages.render.border.bordered_source`, so the
        render does not copy it again; 0 for the input colour itself)
    image : the render, like ``color`` (render)
    started : stage name -> the waiter its ``start`` returned (see the module docstring)
    """

    color: np.ndarray
    depth_m: np.ndarray
    rig: object
    fx_px: float | None = None
    max_range_m: float = 10.0
    registered_m: np.ndarray | None = None
    filled_m: np.ndarray | None = None
    lens: object = None
    signed_coc_px: np.ndarray | None = None
    coc_max_px: float | None = None
    source: np.ndarray | None = None
    source_linear: bool | None = None
    source_border_px: int = 0
    image: np.ndarray | None = None
    started: dict = field(default_factory=dict)

    def replace(self, **changes) -> "FrameState":
        """A copy with *changes*."""
        return dataclasses.replace(self, **changes)


@dataclass
class StageOutput:
    """What :meth:`Stage.run` returns: new state fields, the trace's one-line reason and its detail (plain data),
    and whether the stage found nothing to do after all (e.g. a render that copied every pixel)."""

    updates: dict
    reason: str = ""
    detail: dict = field(default_factory=dict)
    skipped: bool = False


class Stage:
    """Base of the pipeline's stages (see the module docstring); subclasses set :attr:`name` and :meth:`run`."""

    name: str = ""
    #: the stage before which :meth:`start` runs, or None
    starts_before: str | None = None

    def skip(self, state: FrameState, options) -> str | None:
        """Why there is nothing to do for this frame, or None."""
        return None

    def passthrough(self, state: FrameState, options) -> dict:
        """The stage's outputs when it is skipped (new state fields)."""
        return {}

    def plan(self, state: FrameState, options):
        """How to run on this frame (a plan object recorded in the trace), or None when the stage has no choice."""
        return None

    def start(self, state: FrameState, options):
        """Start work early (see the module docstring); returns a waiter or None."""
        return None

    def run(self, state: FrameState, plan, options) -> StageOutput:
        """Do the work; returns the new state fields and what to record."""
        raise NotImplementedError
