"""The registration stage: depth drawn into the colour camera (:func:`pcdof.stages.register.register_depth`)."""

from __future__ import annotations

import numpy as np

from ..base import FrameState, Stage, StageOutput


class RegisterStage(Stage):
    """Registered depth on the colour grid; skipped for a rig whose cameras coincide."""

    name = "register"

    def skip(self, state: FrameState, options) -> str | None:
        from . import needs_registration

        needed, reason = needs_registration(state.rig)
        return None if needed else reason

    def passthrough(self, state: FrameState, options) -> dict:
        return {"registered_m": state.depth_m.copy()}

    def plan(self, state: FrameState, options):
        from . import plan_for

        return plan_for(state.rig)

    def run(self, state: FrameState, plan, options) -> StageOutput:
        from ...camera import RGBDFrame
        from . import needs_registration, open_coarse_edges, plan_info, register_depth

        depth, edges = open_coarse_edges(register_depth(RGBDFrame(state.color, state.depth_m, state.rig), plan=plan),
                                         state.rig)
        reason = needs_registration(state.rig)[1] + (
            f"; {edges['opened']} px at depth edges left to the colour-guided fill (depth grid "
            f"{edges['scale']:.3g}x coarser)" if edges else "")
        return StageOutput({"registered_m": depth}, reason,
                           {"coverage": float(np.count_nonzero(depth) / depth.size),
                            "plan": plan_info(state.rig, plan), **({"edges": edges} if edges else {})})
