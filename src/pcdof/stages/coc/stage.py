"""The circle-of-confusion stage (see the package docstring)."""

from __future__ import annotations

from ..base import FrameState, Stage, StageOutput


def focused(state: FrameState, options):
    """The options' lens focused as ``options.focus_at`` says, on this frame's depths (:mod:`pcdof.focus`)."""
    from ...focus import resolve_lens

    return resolve_lens(options.lens, options.focus_at, state.registered_m, state.filled_m)


class CocStage(Stage):
    """Signed circle of confusion, pixels, and its largest size, with the lens's focus resolved; the paper method's
    lens has none (the stage then only resolves the focus)."""

    name = "coc"

    def skip(self, state: FrameState, options) -> str | None:
        from ...lens import ThinLens

        return None if isinstance(options.lens, ThinLens) else "the paper method blends by its own weight"

    def passthrough(self, state: FrameState, options) -> dict:
        return {"lens": focused(state, options)}

    def run(self, state: FrameState, plan, options) -> StageOutput:
        lens = focused(state, options)
        # the size |signed| is not kept through the render (4 bytes a pixel): the result derives it at the end
        signed, _, coc_max, share = lens.coc_maps_px(state.filled_m, state.fx_px)
        return StageOutput({"lens": lens, "signed_coc_px": signed, "coc_max_px": coc_max},
                           f"max {coc_max:.2f} px", {"max_coc_px": coc_max, "out_of_focus_share": share})
