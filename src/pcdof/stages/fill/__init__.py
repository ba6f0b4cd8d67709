"""The fill stage: every unknown (0) pixel of a registered depth map gets a depth.

Holes in registered depth are of two kinds. *Disocclusions* (surfaces the colour camera sees but
the depth camera or its projector does not) lie beside near objects, and their true depth is that
of the surface *behind* the object's edge. *Sensor holes* (dark or glossy material, out of range)
lie inside a surface and should be interpolated smoothly over it.

The default method, ``"joint-bilateral"``, handles both with one rule per hole pixel:

1. **Candidates.** Along 16 directions (the 8 king moves and the 8 knight moves, walked as
   8-connected Bresenham lines) find the nearest known pixel. Each direction is one pass over the
   holes (a recurrence: a hole's answer is its neighbour's along the line), so the cost does not
   grow with the size of the holes. Every candidate is a
   known pixel next to a hole; a least-squares plane of 1/z is fitted around each such pixel over
   the known pixels of the same surface, which denoises it and gives its slope. 1/z of a plane is
   affine in pixel coordinates, so the candidate is extrapolated along that plane to the hole
   pixel (for at most 64 pixels at 640 pixels across, a guard against amplified noise).
2. **Surfaces.** Sort the candidate depths and split them into surfaces wherever two neighbours
   differ by more than ``edge_ratio`` (relative): a gap that large is a depth edge, not a slope.
3. **Which surface.** Each surface scores its colour support: the sum over its candidates of a
   joint-bilateral range weight exp(-|c - c_p|^2 / 2 sigma^2) (best match among a few pixels
   walked from the candidate into the known region, which copes with texture) times a spatial
   weight 1 / (r + 20 pixels at 640 pixels across). The farthest surface wins unless a nearer one scores more
   than ``background_bias`` times higher: so a shadow band next to a foreground object takes the
   wall's depth, while a dropout blob inside a dark object keeps the object's depth. Surfaces are
   never averaged with each other.
4. **Interpolate** within the chosen surface with inverse-distance weights 1/r on 1/z. For a
   hole in a plane this is exact: a pair of opposite directions with weights 1/r1, 1/r2 gives the
   linear interpolation of 1/z along their line.
5. **Clean up** deep inside large holes (more than 3 pixels from every candidate, at 640 pixels
   across), where the lines of neighbouring pixels pass different boundary corners and leave
   thin streaks: a 5 x 5 median, twice.

Before these steps, measured pixels next to a depth edge whose colour is the nearer surface's move to it
(:mod:`~pcdof.stages.fill.edges`, in the fill stage with ``"joint-bilateral"``): the depth edge then sits on
the colour edge. Two rules come before and after these steps:

* **Outside the view.** A hole is outside the depth camera's field of view when neither its row
  nor its column has known pixels on both sides (a colour camera wider than the depth camera leaves
  such strips at the frame border). Nothing is measured there, and it is not a disocclusion: by
  default (``border="candidates"``) it is filled from its 16 candidates as any hole (steps 1-5), so
  the surfaces that reach the border continue along their planes, but a nearer surface needs only
  4 times the farthest one's colour support (not ``background_bias``, 6): a near object cut by the
  border stays near where its colour continues, and the wall is not pulled forward where it does
  not. A surface whose planes all run past the measured depth range there is not stopped at the
  range's end (one value over an area): nearer than the nearest measured depth it continues along its
  planes, at most 1.1 times nearer; farther than the farthest, each line holds its measured depth.
  A corner that no line reaches blends the nearest filled pixels up, left, down and right
  (1/d weights on 1/z). ``border="extend"`` continues the plane of the nearest inside pixel along
  the row or column (for at most 64 px at 640 across, then held); ``border="hold"`` holds its depth
  (the rule of earlier releases: constant strips, and triangles in the corners). The choice was
  made on the benchmark of real rigs (:mod:`pcdof.bench.fill_rigs`, tuning seeds; docs/fill.md):
  mean error at outside-view holes 179 mm (candidates), 211 (extend), 306 (hold).
* **Speckles.** A filled pixel whose depth differs from all 8 neighbours by more than
  ``edge_ratio`` takes their median (one pass, after step 5).

Filled values are clamped to the range of the known values (outside the view, to 1.1 times nearer). ``"nearest-background"`` is the same
without colour (always the farthest surface); ``"telea"`` is OpenCV's ``cv2.inpaint`` (Telea), the
usual baseline, which averages across depth edges and so smears foreground depth into
disocclusions.

References
----------
J. Kopf, M. F. Cohen, D. Lischinski, M. Uyttendaele, "Joint bilateral upsampling", SIGGRAPH 2007.
A. Telea, "An image inpainting technique based on the fast marching method", J. Graphics Tools 9(1), 2004.

Modules
-------
* :mod:`~pcdof.stages.fill.methods`: the entry point :func:`fill_depth`, the strategies by name
  (:data:`FILL_METHODS`) and :func:`warmup`
* :mod:`~pcdof.stages.fill.plan`: whether there is work (:func:`needs_fill`) and how it runs (:func:`plan_fill`)
* :mod:`~pcdof.stages.fill.directional`: the directional fill (``"joint-bilateral"``, ``"nearest-background"``),
  its kernels run in order
* :mod:`~pcdof.stages.fill.edges`: measured depth edges moved onto the colour edges before the fill
* :mod:`~pcdof.stages.fill.telea`: OpenCV's Telea inpainting (``"telea"``), the baseline
* :mod:`~pcdof.stages.fill.inputs`: the depth and colour checked and converted for the kernels
* :mod:`~pcdof.stages.fill.rules`: the defaults, constants, directions and codes the kernels share
* :mod:`~pcdof.stages.fill.index`: the holes and the boundary numbered
* :mod:`~pcdof.stages.fill.boundary`: step 1 on the boundary: the sweeps along the 16 lines, the planes of 1/z
* :mod:`~pcdof.stages.fill.surfaces`: the per-hole rules (steps 1-4), inlined into the combine kernel
* :mod:`~pcdof.stages.fill.combine`: the combine kernel, every hole filled from its candidates
* :mod:`~pcdof.stages.fill.lost`: holes with nothing to take a depth from, filled from their neighbours
* :mod:`~pcdof.stages.fill.cleanup`: the median deep inside large holes (step 5) and the speckles
* :mod:`~pcdof.stages.fill.reference`: the plain per-hole specification the kernels are tested against
* :mod:`~pcdof.stages.fill.stage`: the stage of the pipeline (:class:`~pcdof.stages.fill.stage.FillStage`)
"""

from .directional import check_border, fill_joint_bilateral, fill_nearest_background
from .methods import FILL_METHODS, check_fill_method, fill_aligned, fill_depth, warmup
from .plan import FillPlan, needs_fill, plan_fill
from .rules import (BORDER, BORDER_ASSUMPTIONS, BORDER_RULES, DEFAULT_BACKGROUND_BIAS, DEFAULT_BORDER,
                    DEFAULT_EDGE_RATIO, DEFAULT_SIGMA_COLOR, DEFAULT_TELEA_RADIUS_PX, LOST, SURFACE)
from .edges import align_depth_edges
from .telea import fill_telea

__all__ = [
    "BORDER", "BORDER_ASSUMPTIONS", "BORDER_RULES", "DEFAULT_BACKGROUND_BIAS", "DEFAULT_BORDER", "DEFAULT_EDGE_RATIO",
    "DEFAULT_SIGMA_COLOR", "DEFAULT_TELEA_RADIUS_PX", "FILL_METHODS", "FillPlan", "LOST", "SURFACE",
    "align_depth_edges", "check_border", "check_fill_method", "fill_aligned", "fill_depth", "fill_joint_bilateral",
    "fill_nearest_background", "fill_telea", "needs_fill", "plan_fill", "warmup",
]
