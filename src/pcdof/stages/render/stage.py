"""The render stage: the depth of field itself (:func:`pcdof.stages.render.render_image`), physical or the paper's."""

from __future__ import annotations

from ..base import FrameState, Stage, StageOutput

def describe_layers(info: dict) -> str:
    """The physical renderer's info as the trace's one line: its blur layers, foreground pass and tiles."""
    blurred = [f"{l['side']}[{l['coc_px'][0]:g},{l['coc_px'][1]:g})" for l in info["layers"] if l["blurred"]]
    tiles = info.get("tiles", {})
    uniform = sum(l.get("uniform_tiles", 0) for l in info["layers"] if l["blurred"])
    return (f"physical, {len(blurred)} blur layers: {' '.join(blurred)}"
            + ("" if info.get("foreground_pass") else "; no foreground pass (nothing in front of focus)")
            + (f"; tiles of {tiles['tile_px']} px: {tiles['copy_tiles']} of {tiles['tiles']} copied"
               f" (in focus), {uniform} convolved (uniform blur)" if tiles else ""))


class RenderStage(Stage):
    """The rendered image, in the input colour's encoding."""

    name = "render"

    def run(self, state: FrameState, plan, options) -> StageOutput:
        from .methods import METHODS

        estimated = state.source is not state.color  # light above white estimated by the highlights stage
        # the renderer itself, not the checked entry (render_image): the options were checked when the run began,
        # the colour when the frame was made, and the highlights stage's estimate is its own (a second check of a
        # float source reads all of it: 5 ms a 1920x1080 focus change)
        image, info = METHODS[options.method](state.source, state.filled_m, state.lens, fx=state.fx_px,
                                              max_range_m=state.max_range_m, linear=state.source_linear,
                                              quality=options.quality, signed_coc=state.signed_coc_px,
                                              border_most=1.0 if estimated else None,
                                              source_border_px=state.source_border_px)
        skipped = bool(info.pop("skipped", False))
        if estimated:  # rendered from reconstructed linear light: back to the input's encoding
            from ...color import encode_from_linear

            image = state.color.copy() if skipped else encode_from_linear(image, state.color.dtype)
        reason = info.pop("reason", options.method)
        if not skipped and options.method == "physical":
            reason = describe_layers(info)
        return StageOutput({"image": image}, reason, info, skipped=skipped)
