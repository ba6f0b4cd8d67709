"""The stage contract (pcdof.stages.base): every stage has a name, says why it skips, plans and runs on plain
data; the pipeline loops over them, so a new stage is one class and one entry in a list."""

import numpy as np
import pytest

from pcdof import ThinLens
from pcdof.camera import Intrinsics, RGBDFrame, Rig
from pcdof.options import RenderOptions
from pcdof.pipeline import initial_state, run, run_stages
from pcdof.stages import STAGES, FrameState, Stage, StageOutput

W, H = 48, 36
INTR = Intrinsics(W, H, 60.0, 60.0, (W - 1) / 2, (H - 1) / 2)
LENS = ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=1.0)


def frame() -> RGBDFrame:
    rng = np.random.default_rng(3)
    color = rng.integers(0, 200, (H, W, 3), dtype=np.uint8)
    depth = np.full((H, W), 3.0, np.float32)
    depth[10:26, 14:34] = 1.0
    depth[0:4, 0:6] = 0.0  # holes for the fill
    return RGBDFrame(color, depth, Rig.registered(INTR))


class FarWall(Stage):
    """A stage a user might add: everything beyond *wall_m* is moved onto a wall at *wall_m*."""

    name = "far-wall"

    def __init__(self, wall_m: float):
        self.wall_m = wall_m

    def skip(self, state: FrameState, options):
        return None if np.any(state.filled_m > self.wall_m) else f"nothing beyond {self.wall_m} m"

    def run(self, state: FrameState, plan, options) -> StageOutput:
        clamped = np.minimum(state.filled_m, np.float32(self.wall_m))
        return StageOutput({"filled_m": clamped}, f"clamped at {self.wall_m} m",
                           {"moved": int(np.count_nonzero(state.filled_m > self.wall_m))})


def test_the_default_stages_in_order():
    assert [s.name for s in STAGES] == ["register", "fill", "coc", "highlights", "render"]
    for stage in STAGES:
        assert isinstance(stage, Stage)


def test_a_stage_added_to_the_list_runs_between_the_others_and_is_traced():
    options = RenderOptions(LENS, highlights="off")
    f = frame()
    stages = [*STAGES[:2], FarWall(2.0), *STAGES[2:]]
    state, trace = run_stages(initial_state(f), options, stages=stages)
    assert [t.name for t in trace] == ["register", "fill", "far-wall", "coc", "highlights", "render"]
    wall = trace[2]
    assert not wall.skipped and wall.detail["moved"] == int(np.count_nonzero(run(f, options).depth_filled_m > 2.0))
    assert state.filled_m.max() == pytest.approx(2.0)
    # the later stages saw the new depth: the background is blurred as if it stood at 2 m
    at_two = frame()
    at_two = RGBDFrame(at_two.color, np.minimum(np.where(at_two.depth_m > 0, at_two.depth_m, 0), 2.0), at_two.rig)
    np.testing.assert_array_equal(np.abs(state.signed_coc_px[20:, :]), run(at_two, options).coc_px[20:, :])
    # and skipped, with its reason, where it has nothing to do
    _, trace = run_stages(initial_state(f), options, stages=[*STAGES[:2], FarWall(10.0), *STAGES[2:]])
    assert trace[2].skipped and trace[2].reason == "nothing beyond 10.0 m"


def test_stages_see_plain_data_and_record_their_plan():
    result = run(frame(), RenderOptions(LENS, highlights="off"))
    by_name = {t.name: t for t in result.trace}
    assert by_name["fill"].detail["holes"] == 4 * 6 and by_name["fill"].detail["threads"] >= 1
    assert by_name["register"].skipped  # the rig's cameras coincide
    assert by_name["coc"].detail["max_coc_px"] > 1
