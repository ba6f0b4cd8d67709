"""Procedural scenes for the wide benchmark: random layouts over wide ranges, three focus positions.

Unlike :data:`pcdof.synth.SCENES` (one hand-made layout per scene, jittered), every scene type here
draws its whole layout from the seed: room depth, subject, a foreground occluder near the camera (in the
``fence`` scene, a fence of thin poles: in focus at ``near``, over a blurred room),
thin structures (wires, branches, rods), emitters and specular glints. Emitter and glint radiance
is drawn log-uniform over :data:`RADIANCE_RANGE` times diffuse white, so the 8-bit sRGB colour
image clips them (the frame keeps the unclipped linear radiance for the ground truth).

Glints stand in for specular highlights: the shading model is view-independent, so a highlight is
a small bright emissive patch on a surface (what a camera records at that view); the ground truth
sees the same patch through the whole aperture.

Every frame has three focus distances (``focus_m``): ``near`` on the foreground occluder (the
background blurs), ``mid`` on the subject, ``far`` on the background (a strongly blurred foreground
over a sharp background). :func:`lens_for_blur` picks the aperture that gives a chosen largest blur.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..lens import ThinLens
from .scene import Scene
from .scenes import SceneSpec, random_color, random_textured, box, cylinder, quad, room, sphere
from .shading import Material

#: emitter and glint radiance, multiples of diffuse white (drawn log-uniform)
RADIANCE_RANGE = (2.0, 200.0)
#: focus positions of every wide-benchmark frame
FOCUS_POSITIONS = ("near", "mid", "far")
#: emitter hues (linear RGB, largest channel 1)
_HUES = ((1.0, 0.78, 0.5), (1.0, 0.55, 0.25), (0.6, 0.75, 1.0), (1.0, 0.5, 0.8), (0.7, 1.0, 0.6), (1.0, 1.0, 1.0))


#: the lens of a wide frame's ``default_lens`` (focused on the subject, ``focus_m["mid"]``)
DEFAULT_FOCAL_LENGTH_MM, DEFAULT_F_NUMBER = 50.0, 2.0


#: what each object of a wide scene is (``WideSpec.object_groups``)
OBJECT_GROUPS = ("room", "subject", "foreground", "thin", "light", "glint")


@dataclass(frozen=True, eq=False)
class WideSpec(SceneSpec):
    """A :class:`~pcdof.synth.scenes.SceneSpec` with its three focus distances, metres (``near``, ``mid``, ``far``),
    and what each object of the scene is (``object_groups``: one name of :data:`OBJECT_GROUPS` per geometry id)."""

    focus_m: dict = field(kw_only=True)
    object_groups: tuple = field(default=(), kw_only=True)


def _radiance(rng) -> float:
    lo, hi = RADIANCE_RANGE
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _emissive(rng) -> tuple[Material, float]:
    level = _radiance(rng)
    hue = np.asarray(_HUES[int(rng.integers(len(_HUES)))])
    return Material("emissive", emission=tuple(hue * level)), level


def _room(rng, back_z: float, dark: bool) -> list:
    lo, hi = (0.02, 0.2) if dark else (0.2, 0.85)
    half = back_z * rng.uniform(0.7, 1.0)
    return room(floor_y=rng.uniform(0.8, 1.4), ceiling_y=-rng.uniform(1.4, 2.5), back_z=back_z, half_width=half,
                floor=random_textured(rng, scale=(0.1, 0.4)),
                back=Material("noise", random_color(rng, lo, hi), random_color(rng, lo * 0.3, lo), scale_m=rng.uniform(0.05, 0.3),
                              contrast=rng.uniform(1.5, 3.5), seed=int(rng.integers(1 << 20))),
                sides=random_textured(rng, scale=(0.05, 0.3)), ceiling=Material("flat", random_color(rng, lo, hi)))


def _subject(rng, z: float) -> list:
    """A random stack of 1-3 primitives standing around (0, 0, z)."""
    x = rng.uniform(-0.25, 0.25) * z
    objs = []
    for _ in range(int(rng.integers(1, 4))):
        s = rng.uniform(0.06, 0.22)
        c = np.array([x + rng.uniform(-0.2, 0.2), rng.uniform(-0.3, 0.4), z + rng.uniform(0, 0.3)])
        kind = int(rng.integers(3))
        if kind == 0:
            objs.append((sphere(c, s), random_textured(rng), True))
        elif kind == 1:
            objs.append((box(c - s, c + s, yaw_deg=rng.uniform(0, 90)), random_textured(rng), False))
        else:
            objs.append((cylinder(c - (0, s * 1.5, 0), c + (0, s * 1.5, 0), s * 0.6), random_textured(rng), False))
    return objs


def _foreground(rng, z: float) -> list:
    """An occluder near the camera: a table edge from below, a post from a side, or a leaf-like slab."""
    kind = int(rng.integers(3))
    if kind == 0:
        top = rng.uniform(0.12, 0.3) * z * 2
        return [(box((-2.0, top, z), (2.0, top + 0.05, z + 1.0)), random_textured(rng), False)]
    if kind == 1:
        side = rng.choice([-1.0, 1.0])
        x = side * rng.uniform(0.15, 0.4) * z
        w = rng.uniform(0.04, 0.12)
        return [(box((x - w / 2, -3.0, z), (x + w / 2, 3.0, z + w)), random_textured(rng), False)]
    c = np.array([rng.uniform(-0.35, 0.35) * z, rng.uniform(-0.3, 0.3) * z, z])
    s = rng.uniform(0.05, 0.12)
    return [(box(c - (s, s * 0.6, 0.01), c + (s, s * 0.6, 0.01), yaw_deg=rng.uniform(-40, 40)), random_textured(rng),
             False)]


def _thin(rng, count: int, z_range: tuple) -> list:
    """Thin rods and wires (radius 1.5-8 mm) at random depths and angles across the view."""
    objs = []
    mat = random_textured(rng, scale=(0.005, 0.02))
    for _ in range(count):
        z = rng.uniform(*z_range)
        a = np.array([rng.uniform(-0.6, 0.6) * z, rng.uniform(-0.5, 0.5) * z, z])
        ang = rng.uniform(0, 2 * math.pi)
        length = rng.uniform(0.4, 1.5) * z
        b = a + length * np.array([math.cos(ang), math.sin(ang), rng.uniform(-0.2, 0.2)])
        objs.append((cylinder(a, b, rng.uniform(0.0015, 0.008), sections=10), mat, False))
    return objs


def _fence(rng, z: float) -> list:
    """A fence at depth *z*: 5-9 upright poles (8-30 mm across) spread over the view, and one rail across."""
    mat = random_textured(rng, scale=(0.005, 0.02))
    count = int(rng.integers(5, 10))
    xs = np.linspace(-0.55, 0.55, count) * z + rng.uniform(-0.03, 0.03, count) * z
    objs = [(cylinder((x, -3.0, z), (x, 3.0, z), rng.uniform(0.004, 0.015), sections=10), mat, False) for x in xs]
    y = rng.uniform(-0.3, 0.3) * z
    objs.append((cylinder((-3.0, y, z + 0.02), (3.0, y, z + 0.02), rng.uniform(0.004, 0.01), sections=10), mat, False))
    return objs


def _lights(rng, count: int, z_range: tuple, levels: list) -> list:
    """Small emitters (spheres 0.8-4 cm) and lamp panels (5-20 cm) at random depths."""
    objs = []
    for _ in range(count):
        z = rng.uniform(*z_range)
        mat, level = _emissive(rng)
        levels.append(level)
        c = (rng.uniform(-0.6, 0.6) * z, rng.uniform(-0.45, 0.3) * z, z)
        if rng.uniform() < 0.25:
            s = rng.uniform(0.025, 0.1)
            objs.append((quad([(c[0] - s, c[1] - s, z), (c[0] + s, c[1] - s, z), (c[0] + s, c[1] + s, z),
                               (c[0] - s, c[1] + s, z)], facing=(0, 0, 0)), mat, False))
        else:
            objs.append((sphere(c, rng.uniform(0.008, 0.04), subdivisions=2), mat, True))
    return objs


def _glints(rng, count: int, subject: list, levels: list) -> list:
    """Specular glints: tiny bright patches on the subject's surface facing the camera."""
    objs = []
    for mesh, _, _ in subject[:count]:
        c = mesh.bounding_box.centroid.copy()
        c[2] = float(mesh.bounds[0][2]) - 0.002  # just in front of the surface
        c[0] += rng.uniform(-0.3, 0.3) * (mesh.extents[0] / 2)
        c[1] += rng.uniform(-0.3, 0.3) * (mesh.extents[1] / 2)
        mat, level = _emissive(rng)
        levels.append(level)
        objs.append((sphere(c, rng.uniform(0.003, 0.012), subdivisions=2), mat, True))
    return objs


def _build(rng, *, dark: bool, n_thin: int, n_lights: int, kind: str) -> WideSpec:
    back_z = rng.uniform(2.6, 4.4)  # within the sensor range (4.5 m)
    z_fg = rng.uniform(0.45, 0.85)
    z_subject = rng.uniform(1.1, min(2.6, back_z - 0.8))
    levels: list = []
    # drawn in this order (room, subject, foreground, thin, lights, glints): a new part goes last
    room_objs = _room(rng, back_z, dark)
    subject = _subject(rng, z_subject)
    front = _fence(rng, z_fg) if kind == "fence" else _foreground(rng, z_fg)
    parts = (("room", room_objs), ("subject", subject), ("foreground", front),
             ("thin", _thin(rng, n_thin, (z_fg, back_z - 0.3))),
             ("light", _lights(rng, n_lights, (z_subject + 0.3, back_z - 0.1), levels)),
             ("glint", _glints(rng, int(rng.integers(1, 4)), subject, levels)))
    objs = [o for _, part in parts for o in part]
    groups = tuple(name for name, part in parts for _ in part)
    ambient = rng.uniform(0.15, 0.4) if dark else rng.uniform(0.25, 0.5)
    light = (rng.uniform(-0.6, 0.6), -rng.uniform(0.4, 0.9), -rng.uniform(0.3, 0.8))
    scene = Scene(objs, light_dir=light, ambient=ambient, diffuse=rng.uniform(0.5, 0.9))
    focus = {"near": round(z_fg, 3), "mid": round(z_subject, 3), "far": round(back_z - 0.05, 3)}
    lens = ThinLens(focal_length_mm=DEFAULT_FOCAL_LENGTH_MM, f_number=DEFAULT_F_NUMBER, focus_distance_m=focus["mid"])
    return WideSpec(scene, lens, f"{kind}: foreground {z_fg:.2f} m, subject {z_subject:.2f} m, back wall "
                    f"{back_z:.2f} m, {n_thin} thin rods, {len(levels)} emitters/glints",
                    {"emitter_radiance": levels, "back_z_m": back_z}, focus_m=focus, object_groups=groups)


def room_scene(rng: np.random.Generator) -> WideSpec:
    """A lit room: subject, foreground occluder, a few thin rods, a few lamps and glints."""
    return _build(rng, dark=False, n_thin=int(rng.integers(1, 4)), n_lights=int(rng.integers(2, 6)), kind="room")


def thin_scene(rng: np.random.Generator) -> WideSpec:
    """Many thin rods and wires (1.5-8 mm) at every depth in front of the subject and background."""
    return _build(rng, dark=False, n_thin=int(rng.integers(8, 20)), n_lights=int(rng.integers(1, 4)), kind="thin")


def night_scene(rng: np.random.Generator) -> WideSpec:
    """A dim room with many emitters (bokeh lights and lamp panels) behind the subject."""
    return _build(rng, dark=True, n_thin=int(rng.integers(0, 3)), n_lights=int(rng.integers(12, 30)), kind="night")


def fence_scene(rng: np.random.Generator) -> WideSpec:
    """A fence of thin poles near the camera (its "near" focus: in focus over a blurred room behind it)."""
    return _build(rng, dark=False, n_thin=int(rng.integers(0, 3)), n_lights=int(rng.integers(1, 4)), kind="fence")


#: wide-benchmark scene type -> builder(rng) -> WideSpec
WIDE_SCENES = {"room": room_scene, "thin": thin_scene, "night": night_scene, "fence": fence_scene}


def lens_for_blur(depth_m: np.ndarray, fx: float, focus_m: float, max_coc_px: float, *,
                  focal_length_mm: float = 50.0) -> ThinLens:
    """The thin lens focused at *focus_m* whose largest CoC over *depth_m* is *max_coc_px*.

    Parameters
    ----------
    depth_m : (H, W) float ndarray, metres, exact depth of the view (0 = nothing)
    fx : float, focal length of the colour camera in pixels
    focus_m, max_coc_px : float > 0
    focal_length_mm : float, sets the f-number that gives the aperture (CoC = A fx |1/d_f - 1/z|)

    Returns
    -------
    ThinLens (circular aperture)
    """
    z = np.asarray(depth_m, np.float64)
    z = z[z > 0]
    if z.size == 0:
        raise InputError("depth_m has no depth > 0 to choose a lens for")
    if not (math.isfinite(max_coc_px) and max_coc_px > 0 and math.isfinite(focus_m) and focus_m > 0):
        raise InputError(f"focus_m and max_coc_px must be finite numbers > 0; got {focus_m!r}, {max_coc_px!r}")
    spread = max(abs(1 / focus_m - 1 / z.min()), abs(1 / focus_m - 1 / z.max()))
    aperture_m = max_coc_px / (fx * max(spread, 1e-9))
    return ThinLens(focal_length_mm=focal_length_mm, f_number=focal_length_mm * 1e-3 / aperture_m, focus_distance_m=focus_m)


def generate_wide(kind: str, *, seed: int, color_size=(320, 240), depth_size=(256, 212), pixel_samples: int = 2):
    """Build wide scene type *kind* from *seed* and render it through the Kinect-like rig.

    Returns
    -------
    (SyntheticFrame, WideSpec): the frame (8-bit clipped sRGB colour, unclipped linear colour,
    sensor depth with noise and holes, exact depths) and the spec with its focus distances.
    """
    from .frame import check_seed, make_frame
    from .rig import kinect_rig, parse_size

    if kind not in WIDE_SCENES:
        raise InputError(f"kind must be one of {', '.join(WIDE_SCENES)}; got {kind!r}")
    seed = check_seed(seed)
    rig = kinect_rig(parse_size(color_size, "color_size"), parse_size(depth_size, "depth_size"))
    spec = WIDE_SCENES[kind](np.random.default_rng([seed, 7]))
    sf = make_frame(spec.scene, rig, default_lens=spec.default_lens, seed=seed, name=f"{kind}",
                    description=spec.description, metadata=spec.metadata, pixel_samples=pixel_samples)
    return sf, spec
