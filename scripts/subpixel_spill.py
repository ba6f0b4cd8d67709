"""Sub-pixel blur of bright in-focus sources on the wide benchmark: what the ground truth shows, and what an
area-source model of the renderer would score.

    python scripts/subpixel_spill.py --seeds 100-105 --cache out/bench-wide6/cache

Two measurements on the wide benchmark's frames at the smaller lens setting (2.5 % of the width), every
scene type and focus position:

1. **Spill in the ground truth.** For each dark pixel (linear radiance < 0.5, CoC < 1 px) beside a bright
   one (> 4 x white, CoC < 1 px), the share of the bright neighbour's radiance the ray-traced truth adds to
   it. The ray tracer samples each pixel at k x k points (the frame's ``pixel_samples``, 2 here), so
   whether a bright source's sub-pixel blur reaches the next pixel's samples depends on where the source's
   edge lies between sample points, which the input (sampled at the same points) does not record.
2. **An area-source model.** pcdof renders a source of CoC < 1 px as a point (a copy). The model that
   treats each source pixel as its whole area (a box) blurred by its disc spreads it with the kernel
   (box * box * disc) at integer offsets, 3 x 3 for a CoC under 1 px. Applied to the excess over white of
   the in-focus pixels (radiance is linear, so the rest of the render is unchanged), on pcdof ``exact``
   given the true depth and the unclipped linear colour: PSNR change overall and in the depth-edge band.

The ground truths are read from (and written to) the wide benchmark's cache folder (``pcdof bench --only
wide -o DIR`` keeps them in ``DIR/cache``); a missing one is ray traced (minutes per frame).
"""

import argparse
import functools

import numpy as np

from pcdof.bench import wide
from pcdof.color import linear_to_srgb
from pcdof.metrics import depth_edge_band
from pcdof.synth.wide import FOCUS_POSITIONS, WIDE_SCENES, generate_wide, lens_for_blur

SIZE, DEPTH_SIZE = (256, 192), (256, 212)


@functools.lru_cache(maxsize=4096)
def area_kernel(coc_px: float, n: int = 48) -> np.ndarray:
    """(3, 3) kernel of a one-pixel box source blurred by a disc of diameter *coc_px* (< 1) and integrated over
    each destination pixel: (box * box * disc) at integer offsets, by n x n samples of the disc. Sums to 1."""
    r = coc_px / 2
    g = ((np.arange(n) + 0.5) / n * 2 - 1) * r
    ox, oy = np.meshgrid(g, g)
    inside = ox ** 2 + oy ** 2 <= r * r
    ox, oy = (ox[inside], oy[inside]) if inside.any() else (np.zeros(1), np.zeros(1))
    d = np.arange(-1, 2)
    tent_x = np.maximum(0.0, 1 - np.abs(d[:, None] - ox[None, :]))  # (3, S)
    tent_y = np.maximum(0.0, 1 - np.abs(d[:, None] - oy[None, :]))
    k = tent_y @ tent_x.T / ox.size
    return k / k.sum()


def with_area_sources(image: np.ndarray, lin: np.ndarray, coc: np.ndarray, white: float = 1.0) -> np.ndarray:
    """*image* (H, W, 3) linear with the excess over *white* of *lin*'s in-focus pixels (|coc| < 1 px) spread by
    :func:`area_kernel` instead of copied."""
    out = image.astype(np.float64)
    h, w = coc.shape
    for y, x in zip(*np.nonzero((np.abs(coc) < 1) & (lin.max(axis=2) > white))):
        excess = np.maximum(lin[y, x] - white, 0.0)
        k = area_kernel(round(float(abs(coc[y, x])), 3)).copy()
        k[1, 1] -= 1.0  # the copy already placed the whole excess at the centre
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if 0 <= y + dy < h and 0 <= x + dx < w:
                    out[y + dy, x + dx] += k[dy + 1, dx + 1] * excess
    return out.astype(np.float32)


def _scores(image, gt, band):
    err = np.mean((wide.encode_srgb8(image) - gt) ** 2, axis=2)
    return wide.psnr_of_sse(float(err.sum()), err.size), wide.psnr_of_sse(float(err[band].sum()), int(band.sum()))


def spill_shares(lin, gt, coc) -> np.ndarray:
    """Share of a bright in-focus pixel's radiance the truth adds to each dark in-focus 4-neighbour."""
    bright, truth, out = lin.max(axis=2), gt.max(axis=2), []
    inner = np.zeros(coc.shape, bool)
    inner[2:-2, 2:-2] = True
    for shift in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        nb, nc = np.roll(bright, shift, (0, 1)), np.roll(coc, shift, (0, 1))
        sel = inner & (nb > 4) & (bright < 0.5) & (np.abs(nc) < 1) & (np.abs(coc) < 1)
        out.append((truth - bright)[sel] / nb[sel])
    return np.concatenate(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="100-105", help="first-last or comma-separated")
    ap.add_argument("--cache", required=True, help="the wide benchmark's ground-truth cache folder")
    a = ap.parse_args()
    seeds = (list(range(int(a.seeds.split("-")[0]), int(a.seeds.split("-")[1]) + 1)) if "-" in a.seeds
             else [int(s) for s in a.seeds.split(",")])
    blur = wide.scaled_blurs(wide.BLURS_PX, SIZE[0])[0]
    shares, deltas = [], []
    for kind in WIDE_SCENES:
        for seed in seeds:
            sf, spec = generate_wide(kind, seed=seed, color_size=SIZE, depth_size=DEPTH_SIZE)
            lin = sf.color_linear.astype(np.float32)
            for focus in FOCUS_POSITIONS:
                lens = lens_for_blur(sf.depth_color_m, sf.rig.color.fx, spec.focus_m[focus], blur)
                gt_lin = wide.ground_truth(sf, lens, cache_dir=a.cache,
                                            key=["wide", kind, seed, focus, blur, list(SIZE), list(DEPTH_SIZE), 2])
                coc = lens.signed_coc_px(sf.depth_color_m, sf.rig.color.fx)
                shares.append(spill_shares(lin, gt_lin, coc))
                gt = linear_to_srgb(np.clip(gt_lin, 0, 1))
                band = depth_edge_band(sf.depth_color_m, max(3, int(round(blur / 2))))
                point = wide.render_variant("true depth+linear", sf, lens)
                before, after = _scores(point, gt, band), _scores(with_area_sources(point, lin, coc), gt, band)
                deltas.append((after[0] - before[0], after[1] - before[1]))
                print(f"{kind} {seed} {focus} {blur:g}px: point {before[0]:.2f} / {before[1]:.2f}, "
                      f"area {after[0]:.2f} / {after[1]:.2f} dB", flush=True)
    s, d = np.concatenate(shares), np.array(deltas)
    print(f"\n{s.size} dark pixels beside bright in-focus ones; share of the neighbour's radiance the truth adds: "
          f"none (< 1 %) at {np.mean(s < 0.01):.0%}, median {np.median(s):.3f}, 90th percentile "
          f"{np.quantile(s, 0.9):.3f}, mean {s.mean():.4f}")
    print(f"area-source model, {len(d)} cases: mean change {d[:, 0].mean():+.2f} / {d[:, 1].mean():+.2f} dB "
          f"(overall / edge band), worst {d[:, 0].min():+.2f} / {d[:, 1].min():+.2f}, best "
          f"{d[:, 0].max():+.2f} / {d[:, 1].max():+.2f}")


if __name__ == "__main__":
    main()
