"""View-independent shading of ray hits: procedural 3-D albedo textures, Lambert light, emitters.

Everything here is linear light. The radiance leaving a surface point depends only on that point
(its position, its surface normal and its material), never on the ray that found it, so a pinhole
render and a thin-lens render of one scene see exactly the same radiance field.

    radiance = albedo(p) * (ambient + diffuse * max(0, n . l)) + emission

``albedo(p)`` is a solid texture evaluated at the 3-D hit point ``p`` (colour-camera frame,
metres); ``n`` is the outward surface normal (interpolated vertex normals on smooth meshes),
``l`` the unit vector towards a directional light.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..errors import InputError

#: texture kinds: name -> code used by the shading kernel
MATERIAL_KINDS = {"flat": 0, "checker": 1, "stripes": 2, "noise": 3, "marble": 4, "emissive": 5}

_MISS = np.uint32(0xFFFFFFFF)  # Open3D's geometry id for rays that hit nothing


def _rgb(name: str, value) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=np.float64).ravel()
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise InputError(f"{name} must be 3 finite values >= 0 (linear RGB); got {value!r}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class Material:
    """A surface: solid-texture albedo, optional emission, and how the depth sensor sees it.

    Parameters
    ----------
    kind : str, one of :data:`MATERIAL_KINDS`
        ``flat`` (albedo ``color_a``), ``checker`` (3-D checkerboard of cube side ``scale_m``),
        ``stripes`` (bands of width ``scale_m/2`` across ``direction``), ``noise`` (fractal value
        noise of feature size ``scale_m``, contrast-stretched between the two colours), ``marble``
        (stripes bent by noise: wood / marble), ``emissive`` (radiance ``emission``, unlit).
    color_a, color_b : 3 floats, linear albedo in [0, 1]
    scale_m : float, texture feature size in metres (> 0)
    direction : 3 floats, stripe normal (normalised here)
    emission : 3 floats, emitted linear radiance (``emissive`` only; may be well above 1)
    contrast : float, >= 1: steepness of the noise-to-colour mapping (higher = harder blotches)
    dark_glossy : bool, the depth sensor loses blobs of this surface (specular dark materials)
    seed : int, decorrelates the noise of materials that share a kind
    """

    kind: str = "flat"
    color_a: tuple = (0.5, 0.5, 0.5)
    color_b: tuple = (0.1, 0.1, 0.1)
    scale_m: float = 0.1
    direction: tuple = (1.0, 0.0, 0.0)
    emission: tuple = (0.0, 0.0, 0.0)
    contrast: float = 3.0
    dark_glossy: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in MATERIAL_KINDS:
            raise InputError(f"material kind must be one of {sorted(MATERIAL_KINDS)}; got {self.kind!r}")
        object.__setattr__(self, "color_a", _rgb("color_a", self.color_a))
        object.__setattr__(self, "color_b", _rgb("color_b", self.color_b))
        object.__setattr__(self, "emission", _rgb("emission", self.emission))
        d = np.asarray(self.direction, dtype=np.float64).ravel()
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise InputError(f"direction must be a non-zero 3-vector; got {self.direction!r}")
        object.__setattr__(self, "direction", tuple(float(v) for v in d / np.linalg.norm(d)))
        s = float(self.scale_m)
        if not math.isfinite(s) or s <= 0:
            raise InputError(f"scale_m must be a finite number > 0; got {self.scale_m!r}")
        object.__setattr__(self, "scale_m", s)
        c = float(self.contrast)
        if not math.isfinite(c) or c < 1:
            raise InputError(f"contrast must be >= 1; got {self.contrast!r}")
        object.__setattr__(self, "contrast", c)
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "dark_glossy", bool(self.dark_glossy))


def pack_materials(materials) -> dict:
    """Materials -> the flat arrays the shading kernel reads (one row per geometry id)."""
    mats = list(materials)
    return {
        "kind": np.array([MATERIAL_KINDS[m.kind] for m in mats], np.int32),
        "color_a": np.array([m.color_a for m in mats], np.float32).reshape(-1, 3),
        "color_b": np.array([m.color_b for m in mats], np.float32).reshape(-1, 3),
        "scale": np.array([m.scale_m for m in mats], np.float32),
        "direction": np.array([m.direction for m in mats], np.float32).reshape(-1, 3),
        "emission": np.array([m.emission for m in mats], np.float32).reshape(-1, 3),
        "contrast": np.array([m.contrast for m in mats], np.float32),
        "seed": np.array([m.seed for m in mats], np.int64),
    }


# ----------------------------------------------------------------------------- value noise
@njit(cache=True, inline="always")
def _hash01(ix, iy, iz, seed):
    # integer lattice hash (xor of large odd multipliers, then a murmur-style finaliser), in [0, 1)
    h = ((ix * 0x8DA6B343) ^ (iy * 0xD8163841) ^ (iz * 0xCB1AB31F) ^ (seed * 0x165667B1)) & 0xFFFFFFFF
    h ^= h >> 16
    h = (h * 0x7FEB352D) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x846CA68B) & 0xFFFFFFFF
    h ^= h >> 16
    return h * (1.0 / 4294967296.0)


@njit(cache=True, inline="always")
def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)  # quintic: C2-smooth value noise


@njit(cache=True)
def value_noise3(x, y, z, seed):
    """Smooth value noise in [0, 1] at a 3-D point (lattice spacing 1)."""
    fx, fy, fz = math.floor(x), math.floor(y), math.floor(z)
    ix, iy, iz = np.int64(fx), np.int64(fy), np.int64(fz)
    tx, ty, tz = _fade(x - fx), _fade(y - fy), _fade(z - fz)
    acc = 0.0
    for dz in range(2):
        wz = tz if dz else 1.0 - tz
        for dy in range(2):
            wy = ty if dy else 1.0 - ty
            for dx in range(2):
                wx = tx if dx else 1.0 - tx
                acc += wx * wy * wz * _hash01(ix + dx, iy + dy, iz + dz, seed)
    return acc


@njit(cache=True)
def fbm3(x, y, z, seed, octaves):
    """Fractal sum of value noise, normalised to [0, 1] (gain 1/2, lacunarity ~2)."""
    total = 0.0
    amp = 1.0
    norm = 0.0
    f = 1.0
    for o in range(octaves):
        total += amp * value_noise3(x * f + 17.3 * o, y * f - 5.1 * o, z * f + 9.7 * o, seed + 101 * o)
        norm += amp
        amp *= 0.5
        f *= 2.03
    return total / norm


@njit(cache=True, inline="always")
def _stretch(t, contrast):
    v = (t - 0.5) * contrast + 0.5
    return min(1.0, max(0.0, v))


@njit(cache=True)
def _mix(k, px, py, pz, kind, scale, direction, contrast, seed):
    """Weight t in [0, 1] of ``color_b`` in material *k*'s albedo at point p (0 for flat)."""
    code = kind[k]
    s = scale[k]
    if code == 1:
        # the lattice is offset by odd fractions of a cell so that axis-aligned planes at round
        # coordinates (a floor at y = 0.9 m with 0.3 m squares) never lie on a cell boundary
        parity = (math.floor(px / s + 0.1234) + math.floor(py / s + 0.3716) + math.floor(pz / s + 0.2583)) % 2.0
        return 1.0 if parity != 0.0 else 0.0
    if code == 2:
        d = px * direction[k, 0] + py * direction[k, 1] + pz * direction[k, 2]
        f = d / s + 0.1372
        return 1.0 if (f - math.floor(f)) >= 0.5 else 0.0
    if code == 3:
        return _stretch(fbm3(px / s, py / s, pz / s, seed[k], 4), contrast[k])
    if code == 4:
        d = px * direction[k, 0] + py * direction[k, 1] + pz * direction[k, 2]
        n = fbm3(px / s, py / s, pz / s, seed[k], 3)
        return _stretch(0.5 + 0.5 * math.sin(2.0 * math.pi * d / s + 6.0 * n), contrast[k])
    return 0.0


@njit(cache=True, parallel=True)
def shade_hits(origins, directions, t_hit, gid, pid, uv, tri_normal, smooth, face_offset, faces, vnormals,
               kind, ca, cb, scale, direction, emission, contrast, seed, light, ambient, diffuse, background):
    """Linear radiance (N, 3) float32 of N ray hits (see the module docstring for the model).

    Rays that hit nothing (geometry id 0xFFFFFFFF) get *background*. Smooth meshes use the vertex
    normals interpolated with the hit's barycentric coordinates; others the triangle normal.
    """
    n = t_hit.shape[0]
    out = np.empty((n, 3), np.float32)
    for i in prange(n):
        g = gid[i]
        if g == 0xFFFFFFFF:
            for c in range(3):
                out[i, c] = background[c]
            continue
        k = np.int64(g)
        if kind[k] == 5:
            for c in range(3):
                out[i, c] = emission[k, c]
            continue
        t = t_hit[i]
        px = origins[i, 0] + t * directions[i, 0]
        py = origins[i, 1] + t * directions[i, 1]
        pz = origins[i, 2] + t * directions[i, 2]
        if smooth[k]:
            f = face_offset[k] + np.int64(pid[i])
            u = uv[i, 0]
            v = uv[i, 1]
            w = 1.0 - u - v
            a, b, cc = faces[f, 0], faces[f, 1], faces[f, 2]
            nx = w * vnormals[a, 0] + u * vnormals[b, 0] + v * vnormals[cc, 0]
            ny = w * vnormals[a, 1] + u * vnormals[b, 1] + v * vnormals[cc, 1]
            nz = w * vnormals[a, 2] + u * vnormals[b, 2] + v * vnormals[cc, 2]
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if norm > 0:
                nx, ny, nz = nx / norm, ny / norm, nz / norm
        else:
            nx, ny, nz = tri_normal[i, 0], tri_normal[i, 1], tri_normal[i, 2]
        lam = nx * light[0] + ny * light[1] + nz * light[2]
        shade = ambient + diffuse * max(lam, 0.0)
        m = _mix(k, px, py, pz, kind, scale, direction, contrast, seed)
        for c in range(3):
            out[i, c] = ((1.0 - m) * ca[k, c] + m * cb[k, c]) * shade + emission[k, c]
    return out


@njit(cache=True, parallel=True)
def noise_at_points(points, scale, seed):
    """fBm noise in [0, 1] at (N, 3) points with feature size *scale* (used for sensor dropouts)."""
    n = points.shape[0]
    out = np.empty(n, np.float32)
    for i in prange(n):
        out[i] = fbm3(points[i, 0] / scale, points[i, 1] / scale, points[i, 2] / scale, seed, 2)
    return out
