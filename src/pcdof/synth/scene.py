"""A ray-castable synthetic scene: triangle meshes with materials, a directional light, Open3D ray casting.

All geometry lives in the colour camera's frame (OpenCV: x right, y down, z forward, metres).
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ..errors import InputError
from ..runtime.threads import start_parallel_loops
from .shading import Material, pack_materials, shade_hits


def vertex_normals(vertices, faces) -> np.ndarray:
    """(V, 3) float32 unit vertex normals: the area-weighted sum of the adjacent triangles' normals."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length = 2 * area
    acc = np.zeros_like(v)
    for k in range(3):
        np.add.at(acc, f[:, k], fn)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return (acc / np.where(norm > 0, norm, 1.0)).astype(np.float32)


class Scene:
    """Meshes with materials, lit by one directional light plus ambient light.

    Parameters
    ----------
    objects : sequence of (trimesh.Trimesh, Material, bool)
        Each mesh (colour-camera frame, metres, outward-facing triangle winding), its material, and
        whether it is shaded with interpolated vertex normals (True: curved surfaces) or with its
        triangle normals (False: flat faces). Geometry id *i* is the *i*-th object.
    light_dir : 3 floats, direction *towards* the light (normalised here)
    ambient, diffuse : float, weights of the ambient term and of the Lambert term
    background : 3 floats, linear radiance of rays that escape the scene

    Notes
    -----
    The Open3D ``RaycastingScene`` is built on first use and is not pickled: a pickled scene is
    rebuilt from its meshes where it is unpickled.
    """

    def __init__(self, objects, *, light_dir=(-0.35, -0.8, -0.5), ambient: float = 0.3, diffuse: float = 0.85,
                 background=(0.0, 0.0, 0.0)) -> None:
        objs = list(objects)
        if not objs:
            raise InputError("objects must hold at least one (mesh, material, smooth) entry; got none")
        self.meshes: list[trimesh.Trimesh] = []
        self.materials: list[Material] = []
        self.smooth: list[bool] = []
        for i, entry in enumerate(objs):
            if len(entry) != 3:
                raise InputError(f"objects[{i}] must be (mesh, material, smooth); got {len(entry)} items")
            mesh, mat, smooth = entry
            if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
                raise InputError(f"objects[{i}] mesh must be a non-empty trimesh.Trimesh; got {type(mesh).__name__}")
            if not isinstance(mat, Material):
                raise InputError(f"objects[{i}] material must be a Material; got {type(mat).__name__}")
            self.meshes.append(mesh)
            self.materials.append(mat)
            self.smooth.append(bool(smooth))
        light = np.asarray(light_dir, np.float64).ravel()
        if light.shape != (3,) or not np.all(np.isfinite(light)) or np.linalg.norm(light) == 0:
            raise InputError(f"light_dir must be a non-zero 3-vector; got {light_dir!r}")
        self.light_dir = light / np.linalg.norm(light)
        for name, v in (("ambient", ambient), ("diffuse", diffuse)):
            if not math.isfinite(float(v)) or float(v) < 0:
                raise InputError(f"{name} must be a finite number >= 0; got {v!r}")
        self.ambient = float(ambient)
        self.diffuse = float(diffuse)
        self.background = np.asarray(background, np.float64).reshape(3)
        self._packed = pack_materials(self.materials)
        nf = np.array([len(m.faces) for m in self.meshes])
        nv = np.array([len(m.vertices) for m in self.meshes])
        self._face_offset = np.concatenate([[0], np.cumsum(nf)[:-1]]).astype(np.int64)
        v_offset = np.concatenate([[0], np.cumsum(nv)[:-1]]).astype(np.int64)
        self._faces = np.concatenate([np.asarray(m.faces, np.int64) + o for m, o in zip(self.meshes, v_offset)])
        self._vnormals = np.concatenate([vertex_normals(m.vertices, m.faces) for m in self.meshes])
        self._smooth = np.array(self.smooth, np.bool_)
        self._rc = None

    # ------------------------------------------------------------------ ray casting
    @property
    def raycasting(self):
        """The Open3D ``RaycastingScene`` (built on first use)."""
        if self._rc is None:
            import open3d as o3d

            rc = o3d.t.geometry.RaycastingScene()
            for i, mesh in enumerate(self.meshes):
                gid = rc.add_triangles(np.ascontiguousarray(mesh.vertices, np.float32),
                                       np.ascontiguousarray(mesh.faces, np.uint32))
                if gid != i:  # pragma: no cover - Open3D numbers geometries 0, 1, 2, ...
                    raise RuntimeError(f"unexpected Open3D geometry id {gid} for object {i}")
            self._rc = rc
        return self._rc

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_rc"] = None
        return state

    @property
    def dark_glossy(self) -> np.ndarray:
        """(G,) bool: which geometry ids the depth sensor loses in blobs."""
        return np.array([m.dark_glossy for m in self.materials], np.bool_)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> dict:
        """Cast rays ``p(t) = origin + t * direction`` (t parametric, not normalised).

        Parameters
        ----------
        origins, directions : (N, 3) float32 ndarray, metres (colour-camera frame)

        Returns
        -------
        dict of ndarrays: ``t_hit`` (N,) float32 (inf = miss), ``geometry_ids`` (N,) uint32
        (0xFFFFFFFF = miss), ``primitive_ids`` (N,) uint32, ``primitive_uvs`` (N, 2) float32,
        ``primitive_normals`` (N, 3) float32.
        """
        rays = np.empty((origins.shape[0], 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = directions
        ans = self.raycasting.cast_rays(rays)
        return {k: v.numpy() for k, v in ans.items()}

    def shade(self, origins: np.ndarray, directions: np.ndarray, hits: dict) -> np.ndarray:
        """Linear radiance (N, 3) float32 of the hits returned by :meth:`cast` for the same rays."""
        p = self._packed
        start_parallel_loops()
        return shade_hits(
            np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(directions, np.float32),
            hits["t_hit"], hits["geometry_ids"], hits["primitive_ids"], hits["primitive_uvs"],
            hits["primitive_normals"], self._smooth, self._face_offset, self._faces, self._vnormals,
            p["kind"], p["color_a"], p["color_b"], p["scale"], p["direction"], p["emission"], p["contrast"],
            p["seed"], self.light_dir, self.ambient, self.diffuse, self.background,
        )

    def trace(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radiance (N, 3) float32 and parametric hit distance (N,) float32 (inf = miss) of rays."""
        hits = self.cast(origins, directions)
        return self.shade(origins, directions, hits), hits["t_hit"]

    def __repr__(self) -> str:
        return f"Scene({len(self.meshes)} objects, {sum(len(m.faces) for m in self.meshes)} triangles)"
