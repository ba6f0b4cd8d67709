"""Procedural scenes, each built from a random generator (same seed, same scene).

Every builder returns a :class:`SceneSpec`: the ray-castable :class:`~pcdof.synth.scene.Scene`,
the lens that shows the scene's depth-of-field case (``default_lens``), and metadata (what the
scene tests, and exact geometry that tests can check against). Geometry is in the colour
camera's frame (x right, y down, z forward, metres); the camera looks along +z from the origin,
so "up" is -y and the floor is the plane y = +camera height. Scenes are closed rooms (or planes
filling every view) so every camera ray hits something.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import trimesh

from ..lens import ThinLens
from .scene import Scene
from .shading import Material


@dataclass(frozen=True, eq=False)
class SceneSpec:
    """A built scene with its recommended lens and its metadata."""

    scene: Scene
    default_lens: ThinLens
    description: str
    metadata: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- mesh helpers
def quad(corners, *, facing) -> trimesh.Trimesh:
    """Two triangles over 4 corners (in order around the quad), wound to face the point *facing*."""
    v = np.asarray(corners, np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    n = np.cross(v[1] - v[0], v[2] - v[0])
    if np.dot(n, np.asarray(facing, np.float64) - v[0]) < 0:
        faces = faces[:, ::-1]
    return trimesh.Trimesh(v, faces, process=False)


def box(lo, hi, *, yaw_deg: float = 0.0) -> trimesh.Trimesh:
    """Axis-aligned box between corners *lo* and *hi*, turned by *yaw_deg* about its vertical axis."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    if yaw_deg:
        m.apply_transform(trimesh.transformations.rotation_matrix(math.radians(yaw_deg), [0, 1, 0]))
    m.apply_translation((lo + hi) / 2)
    return m


def sphere(center, radius: float, *, subdivisions: int = 4) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    m.apply_translation(center)
    return m


def cylinder(p0, p1, radius: float, *, sections: int = 32) -> trimesh.Trimesh:
    return trimesh.creation.cylinder(radius=radius, segment=np.array([p0, p1], float), sections=sections)


def room(*, floor_y: float, ceiling_y: float, back_z: float, half_width: float, floor: Material,
         back: Material, sides: Material, ceiling: Material, front_z: float = -2.0) -> list:
    """The six inward-facing faces of a box room around the camera (floor y > 0, ceiling y < 0)."""
    x0, x1, y0, y1, z0, z1 = -half_width, half_width, ceiling_y, floor_y, front_z, back_z
    inside = (0.0, 0.0, 0.0)
    return [
        (quad([(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)], facing=inside), floor, False),
        (quad([(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)], facing=inside), ceiling, False),
        (quad([(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)], facing=inside), back, False),
        (quad([(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)], facing=inside), sides, False),
        (quad([(x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0)], facing=inside), sides, False),
        (quad([(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)], facing=inside), ceiling, False),
    ]


def random_color(rng, lo=0.05, hi=0.85) -> tuple:
    return tuple(float(v) for v in rng.uniform(lo, hi, 3))


def random_textured(rng, *, scale=(0.03, 0.1)) -> Material:
    """A random high-contrast textured material."""
    kind = str(rng.choice(["checker", "noise", "stripes", "marble"]))
    a = random_color(rng, 0.45, 0.9)
    b = random_color(rng, 0.02, 0.25)
    d = rng.normal(size=3)
    return Material(kind, a, b, scale_m=float(rng.uniform(*scale)), direction=tuple(d), contrast=3.0,
                    seed=int(rng.integers(1 << 20)))


def _emitter(rng, lo: float, hi: float) -> Material:
    palette = [(1.0, 0.78, 0.5), (1.0, 0.55, 0.25), (0.6, 0.75, 1.0), (1.0, 0.5, 0.8), (0.7, 1.0, 0.6)]
    c = np.asarray(palette[int(rng.integers(len(palette)))]) * rng.uniform(lo, hi)
    return Material("emissive", emission=tuple(c))


WOOD = dict(kind="marble", color_a=(0.55, 0.32, 0.15), color_b=(0.22, 0.11, 0.05), scale_m=0.05, contrast=2.0)
DARK_GLOSSY = Material("flat", (0.025, 0.025, 0.03), dark_glossy=True)


# ----------------------------------------------------------------------------- scenes
def portrait(rng: np.random.Generator) -> SceneSpec:
    """A person in front of a wall, a table edge close to the camera, fairy lights on the wall."""
    floor_y = 1.3
    wall_z = 3.0 + rng.uniform(-0.2, 0.3)
    objs = room(floor_y=floor_y, ceiling_y=-1.4, back_z=wall_z, half_width=2.5,
                floor=Material("checker", (0.6, 0.55, 0.48), (0.16, 0.14, 0.12), scale_m=0.4),
                back=Material("noise", (0.35, 0.5, 0.6), (0.08, 0.15, 0.22), scale_m=0.12, contrast=2.5,
                              seed=int(rng.integers(1 << 20))),
                sides=Material("noise", (0.55, 0.5, 0.4), (0.3, 0.26, 0.2), scale_m=0.2, contrast=2.0, seed=7),
                ceiling=Material("flat", (0.7, 0.7, 0.7)))
    # a framed checkerboard picture and a shelf of books on the wall
    objs.append((box((-0.95, -0.55, wall_z - 0.03), (-0.45, -0.15, wall_z)),
                 Material("checker", (0.9, 0.9, 0.85), (0.03, 0.03, 0.03), scale_m=0.05), False))
    objs.append((box((0.45, -0.08, wall_z - 0.22), (1.25, -0.05, wall_z)), Material(**WOOD), False))
    x = 0.48
    while x < 1.2:
        w = rng.uniform(0.03, 0.07)
        hgt = rng.uniform(0.15, 0.24)
        objs.append((box((x, -0.08 - hgt, wall_z - 0.2), (x + w, -0.08, wall_z - 0.02)),
                     Material("flat", random_color(rng, 0.05, 0.8)), False))
        x += w + 0.005
    for i in range(7):  # fairy lights: small, very bright, far behind the focus plane
        xl = -1.2 + 2.4 * i / 6
        yl = -0.6 + 0.08 * (1 - ((xl / 1.2) ** 2))
        objs.append((sphere((xl, yl, wall_z - 0.05), 0.012, subdivisions=2), _emitter(rng, 6, 12), True))
    # the subject
    xs = rng.uniform(-0.12, 0.12)
    zs = 1.5 + rng.uniform(-0.1, 0.1)
    skin = Material("noise", (0.78, 0.52, 0.4), (0.55, 0.32, 0.24), scale_m=0.04, contrast=1.5,
                    seed=int(rng.integers(1 << 20)))
    hair = Material("noise", (0.12, 0.07, 0.04), (0.03, 0.02, 0.01), scale_m=0.015, contrast=2.0, seed=3)
    shirt = Material("stripes", random_color(rng, 0.3, 0.9), (0.85, 0.85, 0.85), scale_m=0.05, direction=(0.15, 1, 0.1))
    objs.append((sphere((xs, -0.05, zs), 0.105), skin, True))
    objs.append((sphere((xs, -0.08, zs + 0.025), 0.108), hair, True))
    objs.append((cylinder((xs, 0.0, zs), (xs, 0.16, zs), 0.045), skin, False))
    torso = trimesh.creation.cylinder(radius=0.2, height=floor_y - 0.17, sections=48)
    torso.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))
    torso.apply_scale([1.0, 1.0, 0.6])
    torso.apply_translation((xs, (0.17 + floor_y) / 2, zs + 0.02))
    objs.append((torso, shirt, False))
    shoulders = trimesh.creation.capsule(height=0.3, radius=0.07, count=[24, 24])
    shoulders.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))
    shoulders.apply_translation((xs, 0.2, zs + 0.02))
    objs.append((shoulders, shirt, True))
    # a table whose front edge is close to the camera, with a dark glossy mug and a ball on it
    table_z = 0.6 + rng.uniform(0.0, 0.05)
    objs.append((box((-1.3, 0.2, table_z), (1.3, 0.25, 1.25)), Material(**WOOD, seed=11), False))
    objs.append((cylinder((0.3, 0.2, 0.85), (0.3, 0.1, 0.85), 0.04), DARK_GLOSSY, False))
    objs.append((sphere((-0.35, 0.15, 0.9), 0.05), Material("checker", (0.9, 0.2, 0.1), (0.95, 0.9, 0.8),
                                                            scale_m=0.025), True))
    focus = zs - 0.105
    return SceneSpec(Scene(objs), ThinLens(focal_length_mm=85.0, f_number=1.8, focus_distance_m=round(focus, 3)),
                     "a person 1.4-1.6 m away in front of a wall ~3 m away, a table edge 0.6 m away",
                     {"subject_distance_m": float(focus), "wall_z_m": float(wall_z), "table_front_z_m": float(table_z)})


def fence(rng: np.random.Generator) -> SceneSpec:
    """Focus through a picket fence and thin branches onto a subject in front of a hedge."""
    floor_y = 1.2
    objs = room(floor_y=floor_y, ceiling_y=-2.5, back_z=4.0, half_width=3.0,
                floor=Material("noise", (0.35, 0.3, 0.2), (0.1, 0.12, 0.05), scale_m=0.1, seed=5),
                back=Material("noise", (0.35, 0.6, 0.2), (0.02, 0.08, 0.02), scale_m=0.06, contrast=3.5,
                              seed=int(rng.integers(1 << 20))),
                sides=Material("noise", (0.3, 0.5, 0.2), (0.03, 0.1, 0.03), scale_m=0.08, contrast=3.0, seed=9),
                ceiling=Material("flat", (0.55, 0.7, 0.9)))
    zs = 2.5 + rng.uniform(-0.2, 0.2)
    xs = rng.uniform(-0.3, 0.3)
    objs.append((sphere((xs, 0.03, zs), 0.22), Material("marble", (0.9, 0.85, 0.75), (0.35, 0.1, 0.1), scale_m=0.08,
                                                        direction=(1, 0.4, 0.2), seed=2), True))
    objs.append((box((xs - 0.17, 0.25, zs - 0.17), (xs + 0.17, floor_y, zs + 0.17)),
                 Material("checker", (0.85, 0.8, 0.2), (0.1, 0.1, 0.4), scale_m=0.06), False))
    zf = 1.0 + rng.uniform(-0.1, 0.1)
    fence_wood = Material("marble", (0.75, 0.72, 0.66), (0.4, 0.37, 0.33), scale_m=0.03, direction=(0, 1, 0.1),
                          contrast=2.0, seed=4)
    x = -1.3 + rng.uniform(0, 0.16)
    while x < 1.3:
        objs.append((box((x, -0.35, zf), (x + 0.035, floor_y, zf + 0.02)), fence_wood, False))
        x += 0.16
    for y in (-0.25, 0.6):
        objs.append((box((-1.4, y, zf + 0.02), (1.4, y + 0.04, zf + 0.04)), fence_wood, False))
    bark = Material("noise", (0.25, 0.17, 0.1), (0.06, 0.04, 0.02), scale_m=0.01, seed=6)
    for _ in range(7):  # thin branches in front of the fence, mostly in the upper half of the view
        z = rng.uniform(0.65, 0.85)
        a = np.array([rng.uniform(-0.6, 0.6) * z, rng.uniform(-0.45, 0.0) * z, z])
        ang = rng.uniform(0, 2 * math.pi)
        b = a + rng.uniform(0.25, 0.5) * np.array([math.cos(ang), 0.6 * math.sin(ang), rng.uniform(-0.1, 0.1)])
        objs.append((cylinder(a, b, rng.uniform(0.003, 0.007), sections=12), bark, False))
    focus = zs - 0.22
    return SceneSpec(Scene(objs), ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=round(focus, 3)),
                     "a subject ~2.5 m away seen through a picket fence at ~1 m and thin branches at ~0.75 m",
                     {"subject_distance_m": float(focus), "fence_z_m": float(zf)})


def highlights(rng: np.random.Generator) -> SceneSpec:
    """A subject in focus, many small bright lights far behind it (bokeh balls)."""
    floor_y = 1.0
    objs = room(floor_y=floor_y, ceiling_y=-2.0, back_z=4.3, half_width=3.0,
                floor=Material("checker", (0.25, 0.22, 0.2), (0.05, 0.045, 0.04), scale_m=0.35),
                back=Material("noise", (0.09, 0.08, 0.12), (0.02, 0.02, 0.03), scale_m=0.15, seed=8),
                sides=Material("noise", (0.08, 0.08, 0.1), (0.02, 0.02, 0.03), scale_m=0.15, seed=10),
                ceiling=Material("flat", (0.04, 0.04, 0.05)))
    xs = rng.uniform(-0.15, 0.15)
    zs = 1.2 + rng.uniform(-0.05, 0.05)
    objs.append((sphere((xs, 0.0, zs), 0.14), Material("checker", (0.95, 0.85, 0.3), (0.1, 0.2, 0.6),
                                                       scale_m=0.04), True))
    objs.append((box((xs - 0.12, 0.14, zs - 0.12), (xs + 0.12, floor_y, zs + 0.12)),
                 Material("stripes", (0.8, 0.8, 0.8), (0.3, 0.05, 0.05), scale_m=0.05, direction=(1, 0.5, 0)),
                 False))
    objs.append((box((0.5, 0.6, 2.0), (0.9, floor_y, 2.4), yaw_deg=20), DARK_GLOSSY, False))
    for _ in range(40):
        z = rng.uniform(2.6, 4.1)
        x = rng.uniform(-0.62, 0.62) * z
        y = min(rng.uniform(-0.47, 0.4) * z, floor_y - 0.05)
        objs.append((sphere((x, y, z), rng.uniform(0.012, 0.025), subdivisions=2), _emitter(rng, 5, 20), True))
    focus = zs - 0.14
    return SceneSpec(Scene(objs), ThinLens(focal_length_mm=85.0, f_number=1.4, focus_distance_m=round(focus, 3)),
                     "a subject at ~1.1 m, 40 small lights (radiance 5-20) 2.6-4.1 m away that become bokeh discs",
                     {"subject_distance_m": float(focus)})


def slanted_plane(rng: np.random.Generator) -> SceneSpec:
    """One textured plane filling the view: continuous depth from ~1 m to ~3.5 m, no occlusion."""
    z0 = 1.6
    a = -0.9 + rng.uniform(-0.05, 0.05)  # dz/dy: the top of the view is farther (a floor seen at a slant)
    b = 0.3 + rng.uniform(-0.05, 0.05)  # dz/dx: the right side is farther
    ext = 15.0
    corners = [(x, y, z0 + b * x + a * y) for x, y in ((-ext, -ext), (ext, -ext), (ext, ext), (-ext, ext))]
    objs = [(quad(corners, facing=(0, 0, 0)),
             Material("checker", (0.85, 0.8, 0.65), (0.06, 0.09, 0.16), scale_m=0.1), False)]
    return SceneSpec(Scene(objs, light_dir=(-0.3, -0.6, -0.75)), ThinLens(focal_length_mm=85.0, f_number=1.4, focus_distance_m=z0),
                     "a slanted textured plane: z = z0 + b x + a y, depth ~1-3.6 m in the colour view",
                     {"plane": {"z0_m": z0, "a": float(a), "b": float(b),
                                "formula": "z = z0 / (1 - b*u - a*v), u = (x - cx)/fx, v = (y - cy)/fy"}})


def near_object(rng: np.random.Generator) -> SceneSpec:
    """A small object 0.5 m from the camera on a thin stem, the background 4.2 m away."""
    floor_y = 0.9
    objs = room(floor_y=floor_y, ceiling_y=-2.0, back_z=4.2, half_width=2.2,
                floor=Material("checker", (0.7, 0.7, 0.68), (0.15, 0.15, 0.17), scale_m=0.3),
                back=Material("marble", (0.8, 0.75, 0.6), (0.2, 0.25, 0.4), scale_m=0.25, direction=(1, 0.3, 0),
                              seed=int(rng.integers(1 << 20))),
                sides=Material("noise", (0.6, 0.4, 0.3), (0.2, 0.1, 0.08), scale_m=0.2, seed=12),
                ceiling=Material("flat", (0.7, 0.7, 0.7)))
    c = np.array([rng.uniform(-0.04, 0.04), rng.uniform(-0.03, 0.03), 0.5])
    r = 0.05
    objs.append((sphere(c, r), Material("checker", (0.95, 0.3, 0.1), (0.95, 0.95, 0.9), scale_m=0.015), True))
    objs.append((cylinder(c + (0, r * 0.9, 0), (c[0], floor_y, c[2]), 0.006, sections=16),
                 Material("flat", (0.1, 0.4, 0.1)), False))
    objs.append((box((-0.9, floor_y - 0.45, 1.9), (-0.4, floor_y, 2.3), yaw_deg=25),
                 Material("stripes", (0.9, 0.9, 0.2), (0.1, 0.1, 0.1), scale_m=0.08, direction=(1, 1, 0)), False))
    objs.append((sphere((0.8, floor_y - 0.3, 3.0), 0.3), Material("noise", (0.3, 0.5, 0.9), (0.02, 0.05, 0.2),
                                                                 scale_m=0.08, seed=13), True))
    focus = float(c[2] - r)
    return SceneSpec(Scene(objs), ThinLens(focal_length_mm=50.0, f_number=2.8, focus_distance_m=round(focus, 3)),
                     "a 10 cm ball 0.5 m away on a thin stem, floor and wall up to 4.2 m behind",
                     {"object_center_m": c.tolist(), "object_radius_m": r, "subject_distance_m": focus})


def clutter(rng: np.random.Generator) -> SceneSpec:
    """Many objects on a table (0.7-1.5 m) and on a shelf against the wall (~3 m); hexagonal aperture."""
    floor_y, table_y, shelf_y, wall_z = 1.1, 0.32, 0.05, 3.3
    objs = room(floor_y=floor_y, ceiling_y=-1.6, back_z=wall_z, half_width=2.4,
                floor=Material("checker", (0.55, 0.5, 0.45), (0.12, 0.1, 0.1), scale_m=0.3),
                back=Material("stripes", (0.85, 0.8, 0.6), (0.5, 0.2, 0.15), scale_m=0.12, direction=(1, 0, 0)),
                sides=Material("noise", (0.5, 0.55, 0.5), (0.2, 0.2, 0.25), scale_m=0.2, seed=14),
                ceiling=Material("flat", (0.75, 0.75, 0.75)))
    objs.append((box((-0.9, table_y, 0.7), (0.9, table_y + 0.04, 1.6)), Material(**WOOD, seed=15), False))
    for x in (-0.85, 0.85):
        for z in (0.75, 1.55):
            objs.append((cylinder((x, table_y + 0.04, z), (x, floor_y, z), 0.025, sections=16),
                         Material(**WOOD, seed=16), False))
    objs.append((box((-2.4, shelf_y, wall_z - 0.35), (2.4, shelf_y + 0.04, wall_z)), Material(**WOOD, seed=17), False))
    on_table = []
    for i in range(18):
        table = i < 10
        if table:
            x, z, base = rng.uniform(-0.6, 0.6), rng.uniform(0.8, 1.5), table_y
            s = rng.uniform(0.04, 0.09)
        else:
            x, z, base = rng.uniform(-1.8, 1.8), rng.uniform(wall_z - 0.3, wall_z - 0.15), shelf_y
            s = rng.uniform(0.06, 0.14)
        mat = DARK_GLOSSY if i in (3, 13) else random_textured(rng)
        kind = int(rng.integers(5))
        if kind == 0:
            m, smooth = box((x - s, base - 2 * s, z - s), (x + s, base, z + s), yaw_deg=rng.uniform(0, 90)), False
        elif kind == 1:
            m, smooth = sphere((x, base - s, z), s), True
        elif kind == 2:
            m, smooth = cylinder((x, base, z), (x, base - 2.5 * s, z), s * 0.7), False
        elif kind == 3:
            m = trimesh.creation.cone(radius=s, height=2.5 * s, sections=32)
            m.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))
            m.apply_translation((x, base, z))
            smooth = False
        else:
            m = trimesh.creation.torus(major_radius=s, minor_radius=0.35 * s, major_sections=48, minor_sections=16)
            m.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2 - 0.3, [1, 0, 0]))
            m.apply_translation((x, base - 1.35 * s, z))
            smooth = True
        objs.append((m, mat, smooth))
        if table:
            on_table.append(z - s)
    for _ in range(4):  # a few small lamps high on the wall
        objs.append((sphere((rng.uniform(-1.5, 1.5), rng.uniform(-0.9, -0.4), wall_z - 0.05), 0.02, subdivisions=2),
                     _emitter(rng, 5, 10), True))
    focus = float(min(on_table))
    return SceneSpec(Scene(objs), ThinLens(focal_length_mm=50.0, f_number=1.8, focus_distance_m=round(focus, 3), aperture_blades=6, aperture_rotation_deg=15.0),
                     "18 assorted objects on a table (0.7-1.6 m) and a wall shelf (~3.1 m), hexagonal aperture",
                     {"subject_distance_m": focus})


#: scene name -> builder(rng) -> SceneSpec
SCENES = {
    "portrait": portrait,
    "fence": fence,
    "highlights": highlights,
    "slanted_plane": slanted_plane,
    "near_object": near_object,
    "clutter": clutter,
}
