"""Rigs of real RGB-D devices, drawn from seeds: where the colour camera sees more than the depth camera.

The default synthetic rig (:func:`pcdof.synth.kinect_rig`) has a colour camera inside the depth
camera's view. Real devices differ: a Kinect v2's colour camera is wider than its depth camera
horizontally and narrower vertically (84 x 54 against 71 x 60 degrees), a Kinect v1's (NYU) slightly
wider on both axes, a RealSense D435's colour camera lies inside its depth view (69 x 42 against
87 x 58), and some phones and webcams pair a wide colour camera with a narrower depth camera on both
axes. Where the colour camera sees more, registered depth has strips at the frame border that no
depth pixel reaches: what a fill puts there is not measured. :func:`rig_case` renders one procedural
scene through one such rig with the sensor's projector shadows and dropouts; the fill benchmark
(:mod:`pcdof.bench.fill_rigs`) scores the fill on them.

Fields of view are nominal (datasheets and published calibrations); each seed draws the baseline,
the mounting rotation, the principal points and the sensor's dropout threshold around them.
"""

from __future__ import annotations

import math

import numpy as np

from ..camera import Intrinsics, Rig
from ..errors import InputError
from .rig import rotation_xyz

#: device -> colour (h, v) field of view, depth (h, v) field of view (degrees), baseline (m), projector
#: offset from the depth camera (m, along x), depth width as a share of the colour width
RIG_KINDS = {
    "kinect-v2": ((84.1, 53.8), (70.6, 60.0), 0.052, 0.01, 0.8),
    "kinect-v1": ((62.0, 48.6), (58.5, 45.6), 0.025, 0.075, 1.0),
    "d435": ((69.4, 42.5), (87.0, 58.0), 0.015, 0.025, 1.0),
    "wide-both": ((90.0, 73.7), (75.0, 60.0), 0.04, 0.05, 0.8),
}
#: scene builders the cases cycle through: hand-made layouts of :data:`pcdof.synth.SCENES` (dark glossy
#: dropouts, fences, thin stems, near objects) and random layouts of :data:`pcdof.synth.wide.WIDE_SCENES`
SCENE_KINDS = ("portrait", "fence", "highlights", "near_object", "clutter", "room", "thin")


def _intrinsics(width: int, fov_deg, rng) -> Intrinsics:
    """Pinhole intrinsics *width* pixels wide with horizontal and vertical fields of view *fov_deg*."""
    th, tv = (math.tan(math.radians(f) / 2) for f in fov_deg)
    height = max(8, int(round(width * tv / th)))
    fx, fy = 0.5 * width / th, 0.5 * height / tv
    off = rng.uniform(-0.01, 0.01, 2) * (width, height)
    return Intrinsics(width, height, fx, fy, (width - 1) / 2 + off[0], (height - 1) / 2 + off[1],
                      (0.0, 0.0, 0.0, 0.0, 0.0))


def sensor_rig(kind: str, color_width: int, rng: np.random.Generator):
    """A rig of device *kind* and its depth-sensor model, jittered by *rng*.

    Parameters
    ----------
    kind : str, a key of :data:`RIG_KINDS`
    color_width : int >= 32, colour image width in pixels (the height follows the fields of view)
    rng : numpy Generator

    Returns
    -------
    (Rig, DepthSensorModel)
    """
    from .rig import MAX_RANGE_M
    from .sensor import DepthSensorModel

    if kind not in RIG_KINDS:
        raise InputError(f"kind must be one of {', '.join(RIG_KINDS)}; got {kind!r}")
    if isinstance(color_width, bool) or not isinstance(color_width, (int, np.integer)) or not 32 <= color_width <= 8192:
        raise InputError(f"color_width must be an integer in [32, 8192]; got {color_width!r}")
    color_fov, depth_fov, baseline, projector, depth_share = RIG_KINDS[kind]
    color = _intrinsics(int(color_width), color_fov, rng)
    depth = _intrinsics(max(32, int(round(color_width * depth_share))), depth_fov, rng)
    side = -1.0 if rng.uniform() < 0.5 else 1.0  # the depth camera left or right of the colour camera
    T = np.eye(4)
    T[:3, :3] = rotation_xyz(rng.uniform(-0.5, 0.5, 3))
    T[:3, 3] = (side * baseline * rng.uniform(0.8, 1.2), rng.uniform(-0.002, 0.002), rng.uniform(-0.002, 0.002))
    model = DepthSensorModel(projector_offset_m=(side * projector, 0.0, 0.0),
                             dropout_threshold=float(rng.uniform(0.45, 0.65)))
    return Rig(color, depth, T, depth_scale=0.001, max_range_m=MAX_RANGE_M), model


def rig_case(seed: int, *, color_width: int = 256, pixel_samples: int = 1):
    """Case *seed*: scene ``SCENE_KINDS[seed % 7]`` built from the seed, shot by rig ``RIG_KINDS``' entry
    ``seed % 4`` (so any 28 consecutive seeds hold every pairing), jittered by the seed.

    Parameters
    ----------
    seed : int in [0, 2**63 - 1]
    color_width : int, colour width in pixels
    pixel_samples : int, colour pixel filter (see :func:`pcdof.synth.make_frame`)

    Returns
    -------
    SyntheticFrame, its ``metadata`` with "rig" (the kind) and "scene_kind"
    """
    from .frame import check_seed, make_frame
    from .scenes import SCENES
    from .wide import WIDE_SCENES

    seed = check_seed(seed)
    scene_kind = SCENE_KINDS[seed % len(SCENE_KINDS)]
    rig_kind = tuple(RIG_KINDS)[seed % len(RIG_KINDS)]
    if scene_kind in SCENES:
        spec = SCENES[scene_kind](np.random.default_rng([seed, 0]))
    else:
        spec = WIDE_SCENES[scene_kind](np.random.default_rng([seed, 7]))
    rig, model = sensor_rig(rig_kind, color_width, np.random.default_rng([seed, 11]))
    return make_frame(spec.scene, rig, default_lens=spec.default_lens, seed=seed, name=f"{scene_kind}/{rig_kind}",
                      description=spec.description, metadata={**spec.metadata, "rig": rig_kind,
                                                              "scene_kind": scene_kind},
                      sensor=model, pixel_samples=pixel_samples)
