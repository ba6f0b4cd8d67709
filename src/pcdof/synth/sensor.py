"""Depth-sensor model: what a Kinect-like structured-light camera reports for a synthetic scene.

Starting from the exact z-depth seen by each depth pixel (ray cast through the pixel centre):

* **projector shadow**: the IR pattern comes from a projector beside the depth camera; a point the
  projector cannot see (another surface in the way, or the surface faces away from it) has no
  depth. Holes therefore appear beside near objects, on the side away from the projector;
* **dark glossy dropouts**: on materials marked ``dark_glossy`` the pattern is lost in blobs
  (fractal noise of the 3-D point above a threshold);
* **noise**: Gaussian, sigma(z) = ``noise_coeff`` * z^2 (Khoshelham & Elberink 2012 measure
  ~1.4e-3 z^2 m for the Kinect), then quantised to the depth file's unit (``rig.depth_scale``);
* **range**: depths outside [``min_range_m``, ``rig.max_range_m``] are holes.

References
----------
K. Khoshelham, S. O. Elberink, "Accuracy and resolution of Kinect depth data for indoor mapping
applications", Sensors 12(2), 2012.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Rig
from ..errors import InputError
from ..runtime.threads import start_parallel_loops
from .scene import Scene
from .shading import noise_at_points


@dataclass(frozen=True)
class DepthSensorModel:
    """Parameters of the depth sensor's errors.

    Parameters
    ----------
    noise_coeff : float, 1/m: noise standard deviation is ``noise_coeff * z**2`` metres
    min_range_m : float, nearer depths are holes
    projector_offset_m : 3 floats, IR projector position in the depth camera's frame, metres
    shadow_tolerance_m : float, how far in front of a point an occluder must be to shadow it
    dropout_scale_m : float, feature size of the dropout blobs on dark glossy surfaces
    dropout_threshold : float in [0, 1], larger = fewer dropouts (noise above it is lost)
    """

    noise_coeff: float = 1.4e-3
    min_range_m: float = 0.4
    projector_offset_m: tuple = (0.075, 0.0, 0.0)
    shadow_tolerance_m: float = 0.002
    dropout_scale_m: float = 0.08
    dropout_threshold: float = 0.55

    def __post_init__(self) -> None:
        for name in ("noise_coeff", "min_range_m", "shadow_tolerance_m", "dropout_scale_m", "dropout_threshold"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0:
                raise InputError(f"{name} must be a finite number >= 0; got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        off = np.asarray(self.projector_offset_m, np.float64).ravel()
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise InputError(f"projector_offset_m must be 3 finite numbers; got {self.projector_offset_m!r}")
        object.__setattr__(self, "projector_offset_m", tuple(float(v) for v in off))


def depth_rays(rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """Origins and directions (N, 3) float32 in the colour frame of the depth camera's pixel-centre rays.

    The directions are ``R @ (u, v, 1)`` so the parametric hit distance equals the z-depth in the
    depth camera's frame.
    """
    d = rig.depth
    xs = (np.arange(d.width, dtype=np.float64) - d.cx) / d.fx
    ys = (np.arange(d.height, dtype=np.float64) - d.cy) / d.fy
    u, v = np.meshgrid(xs, ys)
    local = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3)
    R = rig.T_color_from_depth[:3, :3]
    t = rig.T_color_from_depth[:3, 3]
    dirs = (local @ R.T).astype(np.float32)
    origins = np.broadcast_to(t.astype(np.float32), dirs.shape).copy()
    return origins, dirs


def simulate_depth(scene: Scene, rig: Rig, *, rng: np.random.Generator, model: DepthSensorModel | None = None,
                   dropout_seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Noisy sensor depth and exact depth of *scene* as seen by the rig's depth camera.

    Parameters
    ----------
    scene : Scene
    rig : Rig
    rng : numpy Generator, source of the depth noise
    model : DepthSensorModel, default ``DepthSensorModel()``
    dropout_seed : int, seed of the dropout-blob noise field

    Returns
    -------
    depth_m : (h, w) float32 ndarray, metres, 0 = hole: what the sensor reports (quantised)
    depth_clean_m : (h, w) float32 ndarray, metres: exact z-depth in the depth camera (0 = nothing hit)
    """
    model = model or DepthSensorModel()
    h, w = rig.depth.height, rig.depth.width
    origins, dirs = depth_rays(rig)
    hits = scene.cast(origins, dirs)
    t = hits["t_hit"]
    hit = np.isfinite(t)
    clean = np.where(hit, t, 0.0).astype(np.float32)

    idx = np.flatnonzero(hit)
    if idx.size == 0:  # the depth camera sees nothing
        return np.zeros((h, w), np.float32), clean.reshape(h, w)
    pts = origins[idx] + t[idx, None] * dirs[idx]
    # projector shadow: cast from the projector towards each point; blocked if something is hit first
    R = rig.T_color_from_depth[:3, :3]
    proj = (R @ np.asarray(model.projector_offset_m) + rig.T_color_from_depth[:3, 3]).astype(np.float32)
    to_pt = (pts - proj).astype(np.float32)
    dist = np.linalg.norm(to_pt, axis=1)
    ph = scene.cast(np.broadcast_to(proj, to_pt.shape).copy(), to_pt)
    blocked = ph["t_hit"] * dist < dist - model.shadow_tolerance_m
    normals = hits["primitive_normals"][idx]
    facing_away = np.einsum("ij,ij->i", normals, -to_pt) <= 0
    lost = blocked | facing_away
    # dark glossy surfaces lose the pattern in blobs
    glossy = scene.dark_glossy[hits["geometry_ids"][idx].astype(np.int64)]
    if glossy.any():
        start_parallel_loops()
        blob = noise_at_points(np.ascontiguousarray(pts[glossy], np.float32), model.dropout_scale_m,
                               int(dropout_seed))
        g = np.flatnonzero(glossy)
        lost[g[blob > model.dropout_threshold]] = True

    z = t[idx].astype(np.float64)
    noisy = z + rng.standard_normal(z.shape) * model.noise_coeff * z * z
    noisy = np.round(noisy / rig.depth_scale) * rig.depth_scale
    lost |= (noisy < model.min_range_m) | (noisy > rig.max_range_m)
    depth = np.zeros(h * w, np.float32)
    depth[idx[~lost]] = noisy[~lost]
    return depth.reshape(h, w), clean.reshape(h, w)
