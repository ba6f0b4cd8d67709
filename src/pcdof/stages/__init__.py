"""The pipeline's stages, each a package with its public entry points, one module per concern, its plan and its
plain reference (``reference.py``, the specification every fast path is tested against).

:data:`STAGES` lists the stages :func:`pcdof.pipeline.run` runs, in order; the contract they follow is
:mod:`pcdof.stages.base`. Importing this package loads no kernels: each stage imports its work when it runs.
"""

from .base import FrameState, Stage, StageOutput
from .coc.stage import CocStage
from .fill.stage import FillStage
from .highlights.stage import HighlightsStage
from .register.stage import RegisterStage
from .render.stage import RenderStage

#: the pipeline's stages, in the order they run
STAGES = (RegisterStage(), FillStage(), CocStage(), HighlightsStage(), RenderStage())

__all__ = ["STAGES", "FrameState", "Stage", "StageOutput", "RegisterStage", "FillStage", "CocStage",
           "HighlightsStage", "RenderStage"]
