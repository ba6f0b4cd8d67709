"""Highlight reconstruction: the radiance of clipped pixels, estimated before the blur.

A sensor, or an 8-bit sRGB encoding, clips every channel at 1 (diffuse white). Blurring a clipped
lamp of true radiance 50 spreads 1, not 50, over its bokeh disc: the disc comes out dim and grey.
These functions raise clipped channels towards a radiance estimate so the blur spreads about the
right amount of light. They only apply to clipped input (8-bit or 16-bit sRGB, clipped linear
data); linear/HDR input (EXR, float TIFF/NPY, 16-bit linear) must be passed through untouched
(:func:`needs_reconstruction` says which).

The work is in two halves: what reads the colour only (decoding 8/16-bit codes, the clipped mask,
the blobs and their pixels' statistics: :func:`prepare_highlights`) and what needs the circle of
confusion (each blob's blur and level: :func:`reconstruct_prepared`), so the pipeline can do the
first while the depth stages run. Together they give :func:`reconstruct_highlights`' values.

Only clipped channels change, and only upwards: a channel below the clip level was measured. So a
render from the reconstruction, encoded with clipping at white again, keeps every output pixel
within the input's per-channel range (a raised channel already held the encoding's top code).

Assumptions (what the estimates rely on)
----------------------------------------
* A channel is clipped where it reaches ``clip_level`` (default 254.5/255 encoded, i.e. the top
  8-bit code); its true radiance there is at least the clip level.
* A clipped blob (8-connected pixels with a clipped channel) is one light source or one specular
  glint with one radiance per channel.
* ``prior`` (what ``auto`` runs): the radiance of a clipped channel is log-uniform between the clip
  level and :data:`PRIOR_MAX` times diffuse white, and a light's channels differ by at most a factor
  :data:`MAX_CHANNEL_RATIO` (its colour's saturation), so where most of a blob's pixels clipped in a
  channel have another channel measured (below the clip level), the prior ends at that ratio times
  their median measured value: a barely clipped, strongly coloured surface is not a lamp (both
  bounds are assumptions about scenes, chosen on the wide benchmark's tuning seeds, below). The
  blob is blurred by the disc of its circle of confusion (the median over its pixels, from the
  render's own CoC map, clamped like the renderer's) and shown clipped at white, sRGB-encoded; the
  level chosen per blob and channel minimises the expected sum of squared differences of that
  display from the truth, over the prior (:func:`expected_best_level`, a 32-point quadrature). A
  blob that is not blurred (CoC below 1 px), or whose blurred light shows white whatever its
  radiance, keeps its value; the more thinly its light is spread, the higher the level. The blob's
  edge pixels (with a 4-neighbour outside it) are partly covered by the source: given that they
  clipped, their expected value is (L + clip) / 2 (coverage even over the part of (0, 1) that
  clips), and they are raised to that instead of L. Overlapping footprints, occlusion by nearer
  layers and the renderer's exact kernel are not modelled.
* ``prior-rim``: ``prior`` times the likelihood of the blob's edge counts under the ``rim`` model
  (:func:`rim_likelihood`).
* ``rim``: the source is sharp in the input and sampled by a box pixel filter, so a pixel on its
  edge sees ``alpha * L + (1 - alpha) * B`` with coverage alpha spread evenly over (0, 1). The
  share of edge pixels that stay below the clip level is then about ``(1 - B) / (L - B)``:
  counting clipped and unclipped edge pixels measures L. Where too few edge pixels are unclipped
  (a very bright or tiny source) the estimate is only a lower bound and ``gain`` is used instead.
  The wide benchmark's ray tracer samples two rays per pixel, so its edge coverage is 0, 1/2 or 1,
  not even: its edges say little beyond "L >= 2 - B", which is why the rim evidence does not help
  there (real optics and sensors blur edges continuously; not measured on real frames).
* ``gain``: every clipped channel of a blob gets ``gain`` times diffuse white (times the channel's
  share of the blob's colour, which relates clipped channels to each other).

How the default was chosen
--------------------------
Rule, stated before the measurement (:func:`pcdof.bench.wide.choose_highlights`): on the tuning seeds
0-4 (90 cases; ``pcdof bench --only wide-tune --seeds 5 --wide-size 256x192``), pcdof balanced on
measured input, the setting with the largest mean change from ``off`` per case among those whose
every case loses at most 0.25 dB to ``off``, overall and in the depth-edge band. Mean change / worst
case / worst edge band (dB), tuning seeds:

* gain 2 +1.34 / -0.12 / -0.16; gain 3 +1.94 / -0.39 / -0.56; gain 4 +2.19 / -1.00 / -1.39
* rim +1.87 / -0.26 / -0.38
* prior, no channel-ratio bound, max 8 +1.43 / -0.02 / -0.02; 12 +1.70 / -0.05 / -0.06;
  16 +1.86 / -0.13 / -0.19; 20 +1.97 / -0.58 / -0.75; 24 +2.04 / -0.95 / -1.22; 32 +2.15 / -1.67 / -2.10
* prior, channel ratio 4 (or 8), max 16 **+1.87 / -0.13 / -0.19**; 24 +2.05 / -0.95 / -1.22;
  32 +2.16 / -1.67 / -2.10
* prior-rim, max 8 +1.68 / 0.00 / 0.00; 12 +1.77 / -0.15 / -0.22; 16 +1.80 / -0.33 / -0.47

The rule picks ``prior`` with a bound of 16 and a channel ratio of 4, now ``auto`` and the default.
Few of these blobs have a measured channel, so the ratio bound barely moves this table; on the
``dof`` benchmark's portrait (a foreground surface barely above white in red only, true 1.03, CoC
6 px) it keeps the blob at 1.46 instead of 3.8. The losses of the larger bounds and gains are blobs
of low radiance (2-4 x white) raised several times too high; the 8-bit input does not say which
blobs those are. What an exact per-blob level would give (the true median radiance of each clipped
channel of each blob, edge pixels as above), pcdof exact with true depth on the tuning seeds: 33.31
dB against 33.95 from the unclipped linear colour, 30.10 with ``off`` and 31.92 with ``auto``: the
model of a blob leaves 0.6 dB, the unknown level 1.4 dB.

The estimate is a guess about light the input never recorded: ``off`` stays available.

Modules
-------
* :mod:`~pcdof.stages.highlights.clipped`: the clipped mask and the blobs (reads the colour only)
* :mod:`~pcdof.stages.highlights.rim`: one level per blob (``gain``, ``rim``) and the rim model's likelihood
* :mod:`~pcdof.stages.highlights.footprints`: a clipped channel blurred by its disc, and its samples
* :mod:`~pcdof.stages.highlights.loss`: the expected displayed error and the levels that minimise it
* :mod:`~pcdof.stages.highlights.prior`: the ``prior`` and ``prior-rim`` estimates
* :mod:`~pcdof.stages.highlights.methods`: the strategies by name, :func:`reconstruct_highlights`,
  :func:`parse_highlights`
* :mod:`~pcdof.stages.highlights.prepared`: the stage in two halves (:func:`prepare_highlights`,
  :func:`reconstruct_prepared`)
* :mod:`~pcdof.stages.highlights.checks`: checks of the arguments
"""

from .clipped import CLIP_LEVEL, clipped_mask, needs_reconstruction
from .footprints import MAX_FOOTPRINT_PX, MAX_KERNEL_PX, channel_bound
from .loss import PRIOR_SAMPLES, disc_kernel, expected_best_level, prior_levels
from .methods import HIGHLIGHT_METHODS, NEEDS_COC, parse_highlights, reconstruct_highlights, reconstruct_off
from .prepared import ClippedColor, prepare_highlights, reconstruct_prepared
from .prior import MAX_CHANNEL_RATIO, PRIOR_MAX, reconstruct_prior, reconstruct_prior_rim
from .rim import DEFAULT_GAIN, MAX_GAIN, MIN_EDGE, reconstruct_gain, reconstruct_rim, rim_level, rim_likelihood

__all__ = [
    "CLIP_LEVEL", "DEFAULT_GAIN", "MAX_CHANNEL_RATIO", "MAX_FOOTPRINT_PX", "MAX_GAIN", "MAX_KERNEL_PX", "MIN_EDGE",
    "PRIOR_MAX", "PRIOR_SAMPLES", "HIGHLIGHT_METHODS", "NEEDS_COC", "ClippedColor", "channel_bound", "clipped_mask",
    "disc_kernel", "expected_best_level", "needs_reconstruction", "parse_highlights", "prepare_highlights",
    "prior_levels", "reconstruct_gain", "reconstruct_highlights", "reconstruct_off", "reconstruct_prepared",
    "reconstruct_prior", "reconstruct_prior_rim", "reconstruct_rim", "rim_level", "rim_likelihood",
]
