"""Synthetic RGB-D frames: the rig's colour image and sensor depth, with exact ground truth."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import RGBDFrame, Rig
from ..color import encode_from_linear
from ..errors import InputError
from ..lens import ThinLens
from .render import render_pinhole
from .rig import DEPTH_SIZE, kinect_rig, parse_size
from .scene import Scene
from .scenes import SCENES
from .sensor import DepthSensorModel, simulate_depth

#: default colour pixel filter: the mean of 4 x 4 rays over each pixel's square
PIXEL_SAMPLES = 4
#: largest scene seed: the sensor's dropout noise takes the seed as a 64-bit signed integer
MAX_SEED = 2**63 - 1


def check_seed(seed, name: str = "seed") -> int:
    """*seed* as an int in [0, :data:`MAX_SEED`], or InputError naming *name*."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= MAX_SEED:
        raise InputError(f"{name} must be an integer in [0, 2**63 - 1]; got {seed!r}")
    return int(seed)


@dataclass(frozen=True, eq=False)
class SyntheticFrame:
    """One synthetic RGB-D frame with its ground truth.

    Attributes
    ----------
    name : str, the scene's name
    seed : int
    rig : Rig, colour camera (no distortion) and depth camera
    color : (H, W, 3) uint8 ndarray, sRGB-encoded colour image (radiance above 1 clips)
    color_linear : (H, W, 3) float32 ndarray, linear radiance of the pinhole colour image
    depth_m : (h, w) float32 ndarray, metres, 0 = hole: the sensor's noisy depth (depth camera grid)
    depth_clean_m : (h, w) float32 ndarray, metres: exact z-depth in the depth camera (0 = nothing hit)
    depth_color_m : (H, W) float32 ndarray, metres: exact z-depth in the colour camera
    scene : Scene, the ray-castable scene (colour-camera frame)
    default_lens : ThinLens, the lens the scene was designed for
    description : str
    metadata : dict, scene facts (subject distance, analytic geometry)
    pixel_samples : int, 1 = colour pixels are point samples at their centres; k > 1 = each is the
        mean over its square (k x k rays), and the thin-lens ground truth integrates over the pixel too
    frame : RGBDFrame, ``(color, depth_m, rig)``: what a depth-of-field renderer gets as input
    """

    name: str
    seed: int
    rig: Rig
    color: np.ndarray
    color_linear: np.ndarray
    depth_m: np.ndarray
    depth_clean_m: np.ndarray
    depth_color_m: np.ndarray
    scene: Scene
    default_lens: ThinLens
    description: str = ""
    metadata: dict = field(default_factory=dict)
    pixel_samples: int = 1
    frame: RGBDFrame = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame", RGBDFrame(self.color, self.depth_m, self.rig))


def make_frame(scene: Scene, rig: Rig, *, default_lens: ThinLens, seed: int = 0, name: str = "custom",
               description: str = "", metadata: dict | None = None, sensor: DepthSensorModel | None = None,
               pixel_samples: int = PIXEL_SAMPLES) -> SyntheticFrame:
    """Render a scene through a rig: pinhole colour image, exact depths, simulated sensor depth.

    Parameters
    ----------
    scene : Scene
    rig : Rig, its colour camera must have no distortion
    default_lens : ThinLens
    seed : int in [0, 2**63 - 1], seed of the sensor noise and dropouts
    name, description, metadata : carried into the frame
    sensor : DepthSensorModel, default ``DepthSensorModel()``
    pixel_samples : int, the colour pixel filter: 1 = point samples at the pixel centres, k > 1 =
        box filter (mean of k x k rays over the pixel's square, as a sensor integrates light). The
        ground truth follows the frame's choice, so an in-focus region of it equals the colour image.

    Returns
    -------
    SyntheticFrame
    """
    if not isinstance(scene, Scene):
        raise InputError(f"scene must be a pcdof.synth.Scene; got {type(scene).__name__}")
    if not isinstance(rig, Rig):
        raise InputError(f"rig must be a Rig; got {type(rig).__name__}")
    if not isinstance(default_lens, ThinLens):
        raise InputError(f"default_lens must be a ThinLens; got {type(default_lens).__name__}")
    seed = check_seed(seed)
    color_linear, depth_color = render_pinhole(scene, rig.color, pixel_samples=pixel_samples)
    rng = np.random.default_rng([int(seed), 1])
    depth, clean = simulate_depth(scene, rig, rng=rng, model=sensor, dropout_seed=int(seed))
    color = encode_from_linear(color_linear, np.uint8)
    return SyntheticFrame(name, int(seed), rig, color, color_linear, depth, clean, depth_color, scene, default_lens,
                          description, dict(metadata or {}), int(pixel_samples))


def generate_scene(name: str, *, color_size=(640, 480), depth_size=DEPTH_SIZE, seed: int = 0,
                   max_range_m: float | None = None, sensor: DepthSensorModel | None = None,
                   pixel_samples: int = PIXEL_SAMPLES) -> SyntheticFrame:
    """Build scene *name* from *seed* and render it through the Kinect-like rig.

    Parameters
    ----------
    name : str, a key of :data:`SCENES`
    color_size : (W, H) or "WxH", colour image size in pixels (intrinsics scale with it)
    depth_size : (w, h) or "wxh", depth image size in pixels (default 512x424)
    seed : int in [0, 2**63 - 1], the same seed gives the same scene, images and sensor noise
    max_range_m : float, the depth sensor's range (default :data:`pcdof.synth.rig.MAX_RANGE_M`)
    sensor : DepthSensorModel
    pixel_samples : int, colour pixel filter (see :func:`make_frame`; default a 4 x 4 box filter)

    Returns
    -------
    SyntheticFrame

    Examples
    --------
    >>> sf = generate_scene("portrait", color_size=(64, 48), depth_size=(64, 53), seed=0)
    >>> sf.color.shape, sf.depth_m.shape
    ((48, 64, 3), (53, 64))
    """
    if name not in SCENES:
        raise InputError(f"scene must be one of {sorted(SCENES)}; got {name!r}")
    seed = check_seed(seed)
    cs = parse_size(color_size, "color_size")
    ds = parse_size(depth_size, "depth_size")
    kwargs = {} if max_range_m is None else {"max_range_m": max_range_m}
    rig = kinect_rig(cs, ds, **kwargs)
    spec = SCENES[name](np.random.default_rng([int(seed), 0]))
    return make_frame(spec.scene, rig, default_lens=spec.default_lens, seed=int(seed), name=name,
                      description=spec.description, metadata=spec.metadata, sensor=sensor,
                      pixel_samples=pixel_samples)
