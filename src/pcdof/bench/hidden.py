"""What the hidden background costs: pcdof rendered from the true hidden layers (a counterfactual).

A single RGB-D view never sees what a blurred foreground hides, yet a real lens sees part of it
around the foreground's soft edge. pcdof continues a hidden pixel from the visible layer beside it
(``pcdof.stages.render.reference.owned``). This part of the wide benchmark measures what that guess costs
by giving the renderer what it cannot know: the true hidden layers.

Method. The scene's objects are cut into depth groups, front to back (:func:`depth_groups`). For
group *i* the pinhole frame of the scene with every group in front of *i* removed is ray traced
(:func:`trace_layers`, the colour camera's own rays and pixel filter): its exact depth, the group's
coverage ``m_i`` (the share of each pixel's rays whose first hit is group *i*) and its light
``c_i`` (the mean radiance of those rays, i.e. colour premultiplied by coverage). pcdof's physical
renderer is linear in colour for a fixed depth map (``tests/test_bench_hidden.py`` checks it to
float32 rounding), so ``F_i = render(c_i, depth_i)`` is group *i*'s light at the output and
``a_i = render(m_i, depth_i)`` its opacity, each occluded by the nearer objects left in frame *i*.
The oracle composites them with *over* (:func:`composite_over`)::

    oracle = F_1 + (1 - a_1) (F_2 + (1 - a_2) ( ... F_n))

With one group it is the plain render. Scored against the same ray-traced ground truth as the
wide part, ``PSNR(oracle) - PSNR(plain)`` is what the hidden background costs. Both are rendered
with every tile scattered (``RenderPlan.convolve_uniform`` off): the convolution of uniform tiles
depends on which tiles are uniform, so frames that differ far from a pixel could otherwise render
it differently (measured up to 0.25 in linear light at the rims of bright bokeh discs), which is
not the hidden background's doing. :data:`PLAIN_BUDGET` (the error budget's row, convolution on)
is reported beside it.

What it leaves out, and where it errs:

* background hidden behind an object of the *same* group is still continued by the renderer (the
  subject's primitives among themselves, a lamp among lamps): the cost measured is a lower bound;
* *over* of two separately blurred layers is exact where one of them is sharp (for a pixel, the
  part of the aperture a sharp front blocks does not depend on where the back's light comes
  from, and a sharp back sends all of it from one point) but wrong where both blur alike: it
  misses the correlation, across the aperture, of the front's coverage with the back's colour.
  :data:`ORACLE_MERGED` merges groups whose blurs are closer to each other than to sharp
  (:func:`merge_similar_blur`); the cases where an oracle scores below the plain render bound this
  error (reported seeds, 54 cases: 7 cases, at most 0.46 dB overall and 1.18 dB in the edge band,
  all focused near; merged: 3 cases, at most 0.40 and 0.45 dB, all night scenes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

#: row names: the error budget's plain render (pcdof exact, true depth, unclipped linear colour); the same
#: with every tile scattered; the oracle from the true hidden layers; and the oracle with groups of alike blur merged
PLAIN_BUDGET, PLAIN = "true depth+linear", "true depth+linear, scatter"
ORACLE, ORACLE_MERGED = "hidden layers", "hidden layers, alike blurs merged"
#: depth groups of a wide scene, front to back (see :func:`depth_groups`)
GROUP_NAMES = ("foreground", "thin in front of the subject", "subject and glints",
               "thin and lights behind the subject", "room")


@dataclass(frozen=True)
class HiddenLayer:
    """One depth group as seen with every nearer group removed.

    name : str
    light : (H, W, 3) float32 ndarray, linear radiance premultiplied by coverage (the group's light)
    coverage : (H, W) float32 ndarray in [0, 1], share of each pixel's rays whose first hit is the group
    depth_m : (H, W) float32 ndarray, metres, z-depth of the pixel centre's first hit in this frame
    """

    name: str
    light: np.ndarray
    coverage: np.ndarray
    depth_m: np.ndarray


def depth_groups(object_groups, scene) -> list[tuple[str, list[int]]]:
    """A wide scene's objects cut into depth groups, front to back (empty groups left out).

    The groups (:data:`GROUP_NAMES`): the foreground occluder; thin rods whose nearest point lies in
    front of the subject's; the subject with its glints (which sit on its surface); the thin rods
    behind the subject's nearest point with the lights (drawn between the subject and the back
    wall); the room, which encloses everything.

    Parameters
    ----------
    object_groups : sequence of str, ``WideSpec.object_groups`` (one name per geometry id)
    scene : pcdof.synth.Scene with one mesh per name

    Returns
    -------
    list of (group name, object ids)
    """
    from ..synth.wide import OBJECT_GROUPS

    labels = list(object_groups)
    if len(labels) != len(scene.meshes) or any(lab not in OBJECT_GROUPS for lab in labels):
        raise InputError(f"object_groups must name each of the scene's {len(scene.meshes)} objects with one of "
                         f"{', '.join(OBJECT_GROUPS)}; got {labels!r}")
    near = [float(m.bounds[0][2]) for m in scene.meshes]
    subject = [i for i, lab in enumerate(labels) if lab == "subject"]
    z_subject = min((near[i] for i in subject), default=np.inf)

    def pick(*names, front=None):
        return [i for i, lab in enumerate(labels)
                if lab in names and (front is None or (near[i] < z_subject) == front)]

    groups = (pick("foreground"), pick("thin", front=True), pick("subject", "glint"),
              pick("thin", front=False) + pick("light"), pick("room"))
    return [(name, ids) for name, ids in zip(GROUP_NAMES, groups) if ids]


def _check_groups(groups, n_objects: int) -> list[tuple[str, list[int]]]:
    groups = [(str(name), [int(i) for i in ids]) for name, ids in groups]
    ids = [i for _, g in groups for i in g]
    if not groups or any(not g for _, g in groups) or len(set(ids)) != len(ids) \
            or any(not 0 <= i < n_objects for i in ids):
        raise InputError(f"groups must be non-empty lists of distinct object ids in [0, {n_objects}); got {groups!r}")
    return groups


def trace_layers(scene, intrinsics, groups, *, pixel_samples: int = 1) -> list[HiddenLayer]:
    """Ray trace each depth group with every nearer group removed.

    Parameters
    ----------
    scene : pcdof.synth.Scene that encloses the camera (every ray hits something)
    intrinsics : Intrinsics of the colour camera (no distortion)
    groups : list of (name, object ids), front to back (:func:`depth_groups`); objects in no group
        are left out of every frame
    pixel_samples : int >= 1, the colour image's pixel filter (``SyntheticFrame.pixel_samples``):
        the same k x k rays per pixel as :func:`pcdof.synth.render.render_pinhole`

    Returns
    -------
    list of :class:`HiddenLayer`, one per group. The first layer's frame holds every group: its
    depth is the pinhole frame's, and with a single group holding every object its light is the
    pinhole image (:func:`pcdof.synth.render.render_pinhole`, bit for bit).
    """
    from ..synth.render import pixel_directions
    from ..synth.scene import Scene

    groups = _check_groups(groups, len(scene.meshes))
    if isinstance(pixel_samples, bool) or not isinstance(pixel_samples, (int, np.integer)) or pixel_samples < 1:
        raise InputError(f"pixel_samples must be an integer >= 1; got {pixel_samples!r}")
    k = int(pixel_samples)
    h, w = intrinsics.height, intrinsics.width
    dirs = pixel_directions(intrinsics).astype(np.float32)
    origins = np.zeros_like(dirs)
    offs = [None] if k == 1 else (np.arange(k) + 0.5) / k - 0.5
    layers = []
    for gi, (name, _) in enumerate(groups):
        kept = [i for _, ids in groups[gi:] for i in ids]
        sub = Scene([(scene.meshes[i], scene.materials[i], scene.smooth[i]) for i in kept],
                    light_dir=scene.light_dir, ambient=scene.ambient, diffuse=scene.diffuse,
                    background=scene.background)
        mine = np.zeros(len(kept) + 1, bool)  # sub-scene geometry id -> in group gi (a miss maps to the last)
        mine[:len(groups[gi][1])] = True
        t = sub.cast(origins, dirs)["t_hit"]
        if not np.all(np.isfinite(t)):
            raise InputError(f"scene must enclose the camera; {int(np.sum(~np.isfinite(t)))} rays of group "
                             f"{name!r}'s frame hit nothing")
        light, cover = np.zeros((h * w, 3), np.float64), np.zeros(h * w, np.float64)
        for oy in offs:
            for ox in offs:
                d = dirs if ox is None else dirs + np.array([ox / intrinsics.fx, oy / intrinsics.fy, 0], np.float32)
                hits = sub.cast(origins, d)
                hit = mine[np.minimum(hits["geometry_ids"], len(kept)).astype(np.int64)]
                light[hit] += sub.shade(origins, d, hits)[hit]
                cover += hit
        n = len(offs) ** 2
        layers.append(HiddenLayer(name, (light / n).astype(np.float32).reshape(h, w, 3),
                                  (cover / n).astype(np.float32).reshape(h, w), t.astype(np.float32).reshape(h, w)))
    return layers


def composite_over(lights, opacities) -> np.ndarray:
    """Front-to-back *over*: ``F_1 + (1 - a_1) (F_2 + (1 - a_2) ( ... F_n))``.

    Parameters
    ----------
    lights : sequence of n (H, W, 3) float arrays, each layer's premultiplied light
    opacities : sequence of n - 1 (or n; the last is not used) (H, W) float arrays, the layers' opacity

    Returns
    -------
    (H, W, 3) float32 ndarray
    """
    lights = [np.asarray(f, np.float32) for f in lights]
    opacities = [np.asarray(a, np.float32) for a in opacities]
    if not lights or len(opacities) not in (len(lights) - 1, len(lights)):
        raise InputError(f"lights and opacities must be n >= 1 and n - 1 or n arrays; got {len(lights)} and "
                         f"{len(opacities)}")
    shape = lights[0].shape
    if len(shape) != 3 or shape[2] != 3 or any(f.shape != shape for f in lights) \
            or any(a.shape != shape[:2] for a in opacities):
        raise InputError(f"lights must be (H, W, 3) and opacities (H, W), all of one size; got "
                         f"{[f.shape for f in lights]} and {[a.shape for a in opacities]}")
    out = lights[-1].copy()
    for f, a in zip(lights[-2::-1], opacities[len(lights) - 2::-1]):
        out = f + (1.0 - a)[..., None] * out
    return out


def render_oracle(layers, lens, fx: float, *, quality: str = "exact", max_range_m: float = 10.0,
                  convolve_uniform: bool = True) -> np.ndarray:
    """pcdof's physical render given the true hidden layers (:func:`trace_layers`): each layer's
    light and coverage rendered on its own depth, composited with :func:`composite_over`.

    *convolve_uniform* False renders every tile with the exact scatter (``RenderPlan.convolve_uniform``):
    the convolution of uniform tiles depends on which tiles are uniform, so two frames that differ
    far away could otherwise render one place differently.

    Returns
    -------
    (H, W, 3) float32 ndarray, linear radiance
    """
    from dataclasses import replace

    from ..plans import plan_render
    from ..stages.render import render_image

    layers = list(layers)
    if not layers or not all(isinstance(la, HiddenLayer) for la in layers):
        raise InputError(f"layers must be a non-empty list of HiddenLayer; got {layers!r:.80}")
    plan = replace(plan_render(quality=quality), convolve_uniform=bool(convolve_uniform))

    def draw(image, depth):
        return render_image(image, depth, lens, fx=fx, linear=True, quality=quality, max_range_m=max_range_m,
                            plan=plan)[0]

    lights = [draw(la.light, la.depth_m) for la in layers]
    opacities = [draw(la.coverage, la.depth_m) for la in layers[:-1]]
    return composite_over(lights, opacities)


def merge_similar_blur(groups, layers, lens, fx: float) -> list[tuple[str, list[int]]]:
    """*groups* with each group merged into the one in front of it when their blurs are closer to
    each other than either is to sharp.

    *over* of two separately blurred layers is exact where one of them is sharp and wrong by the
    correlation of the front's coverage with the back's colour across the aperture where both blur
    alike (as blur sizes meet, a single layer is exact: a lens then sees no hidden background). A
    group's blur is the median signed CoC (px) of its pixels in its own frame; groups *i* and *i+1*
    merge when ``|c_i - c_(i+1)| < min(|c_i|, |c_(i+1)|)``.

    Parameters
    ----------
    groups : list of (name, object ids), front to back; layers : :func:`trace_layers` of *groups*
    lens : ThinLens; fx : focal length of the colour camera, px

    Returns
    -------
    list of (name, object ids), front to back (names joined with " + ")
    """
    if len(layers) != len(groups):
        raise InputError(f"layers must be the {len(groups)} layers of groups; got {len(layers)}")
    coc = [float(np.median(lens.signed_coc_px(la.depth_m[la.coverage > 0], fx))) if np.any(la.coverage > 0)
           else None for la in layers]
    out = [(groups[0][0], list(groups[0][1]))]
    for (name, ids), front, back in zip(groups[1:], coc[:-1], coc[1:]):
        if front is not None and back is not None and abs(back - front) < min(abs(back), abs(front)):
            out[-1] = (f"{out[-1][0]} + {name}", out[-1][1] + list(ids))
        else:
            out.append((name, list(ids)))
    return out


def _case_row(case, lens, size, method, image, gt, coc, band) -> dict:
    """One scored row, in the wide part's row format (:func:`pcdof.bench.wide.run_wide`)."""
    from .wide import bucket_sums, encode_srgb8, psnr_of_sse

    kind, seed, focus, blur = case
    err = np.mean((encode_srgb8(image) - gt) ** 2, axis=2)
    return {"scene": kind, "seed": seed, "focus": focus, "blur_px": blur, "blur_share": blur / size[0],
            "f_number": lens.f_number, "focus_distance_m": lens.focus_distance_m, "method": method,
            "psnr": psnr_of_sse(float(err.sum()), err.size), "psnr_edge": psnr_of_sse(float(err[band].sum()), int(band.sum())),
            "sse": bucket_sums(err, coc, band)}


def run_hidden(*, kinds=None, seeds=None, blurs=None, reference_width_px=640, size=(256, 192), depth_size=(256, 212),
               quality: str = "exact", cache_dir=None, progress: bool = True) -> list[dict]:
    """Score the plain renders and the oracles (:func:`render_oracle`) on every wide case.

    Parameters are those of :func:`pcdof.bench.wide.run_wide` (seeds default to its
    :data:`~pcdof.bench.wide.REPORT_SEEDS`, blurs to :data:`~pcdof.bench.wide.BLURS_PX`; the same
    *cache_dir* shares its ray-traced ground truths); *quality* is pcdof's (``exact`` in the budget).

    Returns
    -------
    list of dict, four rows per case (methods :data:`PLAIN_BUDGET`, :data:`PLAIN`, :data:`ORACLE`,
    :data:`ORACLE_MERGED`) in the wide part's format, each with "groups": the number of depth groups
    """
    from tqdm.auto import tqdm

    from ..plans import check_quality
    from . import wide

    check_quality(quality)
    seeds = wide.REPORT_SEEDS if seeds is None else seeds
    blurs = wide.BLURS_PX if blurs is None else blurs
    cases = wide.wide_cases(*wide.checked_cases(kinds, seeds, blurs, size[0], reference_width_px))
    rows, frame = [], None
    for case in tqdm(cases, desc="hidden bench", unit="case", disable=not progress):
        if frame is None or frame.key != case[:2]:
            frame = _Frame.make(case[:2], size, depth_size)
        sf, (_, _, focus, blur) = frame.sf, case
        lens = frame.lens(focus, blur)
        gt, band = wide.case_truth(sf, lens, case, size, depth_size, cache_dir)
        coc = lens.coc_px(sf.depth_color_m, sf.rig.color.fx)
        for method, layers in frame.variants(lens):
            image = render_oracle(layers, lens, sf.rig.color.fx, quality=quality, max_range_m=sf.rig.max_range_m,
                                  convolve_uniform=method == PLAIN_BUDGET)
            rows.append({**_case_row(case, lens, size, method, image, gt, coc, band), "groups": len(layers)})
    return rows


class _Frame:
    """One wide frame with its depth groups, their traced layers cached by grouping."""

    def __init__(self, key, sf, spec):
        self.key, self.sf, self.spec = key, sf, spec
        self.groups = depth_groups(spec.object_groups, spec.scene)
        self._traced = {}

    @classmethod
    def make(cls, key, size, depth_size) -> "_Frame":
        from ..synth.wide import generate_wide

        return cls(key, *generate_wide(key[0], seed=key[1], color_size=size, depth_size=depth_size))

    def lens(self, focus, blur):
        from ..synth.wide import lens_for_blur

        return lens_for_blur(self.sf.depth_color_m, self.sf.rig.color.fx, self.spec.focus_m[focus], blur)

    def layers(self, groups) -> list[HiddenLayer]:
        key = tuple((name, tuple(ids)) for name, ids in groups)
        if key not in self._traced:
            self._traced[key] = trace_layers(self.spec.scene, self.sf.rig.color, groups,
                                             pixel_samples=self.sf.pixel_samples)
        return self._traced[key]

    def variants(self, lens):
        """(method, layers) of every row of a case."""
        whole = [_whole(self.sf)]
        merged = merge_similar_blur(self.groups, self.layers(self.groups), lens, self.sf.rig.color.fx)
        return ((PLAIN_BUDGET, whole), (PLAIN, whole), (ORACLE, self.layers(self.groups)),
                (ORACLE_MERGED, self.layers(merged)))


def _whole(sf) -> HiddenLayer:
    """The frame as one layer: its pinhole colour and exact depth (the plain render's input)."""
    return HiddenLayer("whole frame", sf.color_linear, np.ones(sf.depth_color_m.shape, np.float32), sf.depth_color_m)


def _pairs(rows, plain, oracle) -> list[tuple[dict, dict]]:
    """(plain row, oracle row) of every case that has both."""
    by: dict = {}
    for r in rows:
        by.setdefault((r["scene"], r["seed"], r["focus"], r["blur_px"]), {})[r["method"]] = r
    return [(p[plain], p[oracle]) for p in by.values() if plain in p and oracle in p]


def _selections(pairs) -> list[tuple[str, str, object]]:
    """(group, label, keep(row) -> bool): per focus position and blur, per focus, per scene type, all."""
    from ..synth.wide import FOCUS_POSITIONS

    keys = sorted({(a["focus"], a["blur_px"], a["blur_share"]) for a, _ in pairs},
                  key=lambda k: (FOCUS_POSITIONS.index(k[0]) if k[0] in FOCUS_POSITIONS else 99, k[1]))
    out = [("focus, blur", f"{f}, {100 * s:.3g} % ({b:g} px)", lambda a, f=f, b=b: (a["focus"], a["blur_px"]) == (f, b))
           for f, b, s in keys]
    out += [("focus", f, lambda a, f=f: a["focus"] == f) for f in dict.fromkeys(k[0] for k in keys)]
    out += [("scene", k, lambda a, k=k: a["scene"] == k) for k in dict.fromkeys(a["scene"] for a, _ in pairs)]
    return out + [("all", "all cases", lambda a: True)]


def cost_summary(rows: list[dict], *, plain: str = PLAIN, oracle: str = ORACLE) -> list[dict]:
    """What the hidden background costs (PSNR of *oracle* minus *plain*), per focus position and
    largest blur, per focus position, per scene type, and over all cases.

    Returns
    -------
    list of dict: group ("focus, blur" / "focus" / "scene" / "all"), label, cases, psnr_plain(_edge),
    psnr_oracle(_edge), cost_db and cost_edge_db (mean over cases of PSNR(oracle) - PSNR(plain),
    overall and in the depth-edge band), worst_db and best_db (the smallest and largest per-case cost)
    """
    pairs = _pairs(rows, plain, oracle)
    out = []
    for group, label, keep in _selections(pairs):
        sel = [(a, o) for a, o in pairs if keep(a)]
        if not sel:
            continue
        cost = [o["psnr"] - a["psnr"] for a, o in sel]
        out.append({"group": group, "label": label, "cases": len(sel),
                    "psnr_plain": float(np.mean([a["psnr"] for a, _ in sel])),
                    "psnr_plain_edge": float(np.mean([a["psnr_edge"] for a, _ in sel])),
                    "psnr_oracle": float(np.mean([o["psnr"] for _, o in sel])),
                    "psnr_oracle_edge": float(np.mean([o["psnr_edge"] for _, o in sel])),
                    "cost_db": float(np.mean(cost)),
                    "cost_edge_db": float(np.mean([o["psnr_edge"] - a["psnr_edge"] for a, o in sel])),
                    "worst_db": float(min(cost)), "best_db": float(max(cost))})
    return out


def cost_table(rows: list[dict]) -> str:
    """:func:`cost_summary` as Markdown: the plain render, the oracle, and what the hidden background
    costs by each oracle (:data:`ORACLE`, and :data:`ORACLE_MERGED` where the rows have it)."""
    from . import table_lines

    main = cost_summary(rows)
    merged = {s["label"]: s for s in cost_summary(rows, oracle=ORACLE_MERGED)}
    cells = []
    for s in main:
        m = merged.get(s["label"])
        cells.append((s["label"], s["cases"], f"{s['psnr_plain']:.2f} / {s['psnr_plain_edge']:.2f}",
                      f"{s['psnr_oracle']:.2f} / {s['psnr_oracle_edge']:.2f}",
                      f"{s['cost_db']:.2f} / {s['cost_edge_db']:.2f}", f"{s['worst_db']:+.2f} / {s['best_db']:+.2f}",
                      f"{m['cost_db']:.2f} / {m['cost_edge_db']:.2f}" if m else "-",
                      f"{m['worst_db']:+.2f} / {m['best_db']:+.2f}" if m else "-"))
    return "\n".join(table_lines(
        ("cases", "n", f"{PLAIN} dB, overall / edge", f"{ORACLE} dB", "hidden background costs dB, overall / edge",
         "per case: least / most", f"cost by {ORACLE_MERGED} dB", "per case: least / most"), cells))
