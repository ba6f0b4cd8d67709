"""Synthetic RGB-D scenes with exactly known geometry and a ray-traced thin-lens ground truth.

>>> from pcdof.synth import generate_scene, render_thin_lens
>>> sf = generate_scene("portrait", color_size=(320, 240), seed=0)   # doctest: +SKIP
>>> gt = render_thin_lens(sf, sf.default_lens)                      # doctest: +SKIP
"""

from .frame import SyntheticFrame, generate_scene, make_frame
from .render import (
    GroundTruth,
    aperture_points,
    max_coc_px,
    recommended_samples,
    render_ground_truth,
    render_pinhole,
    render_thin_lens,
)
from .rig import kinect_rig
from .scene import Scene
from .scenes import SCENES, SceneSpec
from .sensor import DepthSensorModel, simulate_depth
from .shading import MATERIAL_KINDS, Material
from .write import write_scene

__all__ = [
    "SCENES", "SceneSpec", "Scene", "Material", "MATERIAL_KINDS", "SyntheticFrame", "generate_scene", "make_frame",
    "render_pinhole", "render_thin_lens", "render_ground_truth", "GroundTruth", "aperture_points",
    "recommended_samples", "max_coc_px", "kinect_rig", "DepthSensorModel", "simulate_depth", "write_scene",
]
