"""Registration: depth from the depth camera, re-sampled in the colour camera's pixel grid.

Each depth pixel is back-projected along its (undistorted) ray, moved into the colour camera
with ``rig.T_color_from_depth`` and projected with the colour intrinsics and distortion. The
depth grid is then drawn as a triangle mesh, two triangles per 2x2 quad of known neighbours,
with 1/z interpolated linearly in the colour image (perspective-correct for planar triangles)
and a z-buffer, so the nearest surface wins and a depth grid coarser than the colour grid
leaves no sampling gaps. Triangles whose corners differ in depth by more than a ratio
(``max_depth_ratio``) span a depth discontinuity and are dropped, so disocclusions and sensor
holes stay 0 instead of being bridged.

The mesh only spans the area between pixel centres, but a depth pixel measures the surface
over its whole footprint. So every known pixel on the edge of the mesh (a corner of a dropped
triangle or a missing neighbour: silhouettes, isolated pixels, one-pixel-wide structures) is
also drawn as its own projected footprint (constant depth, reaching half a depth pixel to each
side except towards a neighbour nearer by more than the discontinuity ratio: that side belongs
to the occluder), after the triangles, where it fills an empty colour pixel or lies in front of
what is there by more than the ratio. That carries a foreground out to its silhouette instead
of leaving a half-pixel band where the background seen by the depth camera shows through, and
nothing measured is lost. This is close to the Azure Kinect SDK's depth-to-colour
transformation (which draws every depth pixel as its footprint), with interpolated depth
inside surfaces.

Drawing keeps 1/z in the output buffer (no division per pixel; the largest value is the
nearest surface) and converts it to z at the end. The output rows are split into bands, one
task each, so threads never write the same pixel: the result does not depend on the number of
threads or tasks.

Everything that depends only on the calibration (the depth camera's rotated, undistorted rays
and the colour camera's lens constants) is computed once per rig and cached. Each call makes
two passes: the depth rows are projected and their quads coded in chunks, then the colour
bands are drawn. How they run (threads, chunks, bands, the small-quad kernel) is a
:class:`pcdof.plans.RegisterPlan`. The passes are numba code that releases the GIL; the calling
thread and ``plan.threads - 1`` helper threads take chunks and bands from an atomic counter and
wait for each other in the operating system, without spinning. So when another process keeps a
core busy, the threads that do get a CPU take over the remaining work instead of waiting,
spinning, for one that does not. (numba's ``prange`` would also
compile the drawing kernel about 2.5 times slower, a cost paid at the first run after every
install, for the same speed once compiled.) :func:`warmup` compiles (or loads from numba's
cache) the kernels and starts the helper threads up front.

Modules
-------
* :mod:`~pcdof.stages.register.reproject`: the entry points (:func:`needs_registration`, :func:`reproject_depth`,
  :func:`register_depth`, :func:`plan_for`, :func:`warmup`) and the discontinuity ratio
* :mod:`~pcdof.stages.register.project`: pass 1, the depth rows projected and their quads coded
* :mod:`~pcdof.stages.register.raster`: pass 2, the colour bands drawn (triangles, then footprints)
* :mod:`~pcdof.stages.register.triangles`: drawing one triangle or quad into the 1/z buffer
* :mod:`~pcdof.stages.register.rig`: the per-calibration constants, cached
* :mod:`~pcdof.stages.register.tasks`: tasks of rows claimed from an atomic counter (:mod:`pcdof.runtime.tasks`),
  and the helper threads
* :mod:`~pcdof.stages.register.constants`: what the kernels share
* :mod:`~pcdof.stages.register.reference`: the plain per-triangle specification the kernels are tested against
* :mod:`~pcdof.stages.register.guided`: a depth grid coarser than the colour in the same camera (phone depth
  photos): the registered depth's edges opened for the colour-guided fill
"""

from .constants import MAX_PRIMITIVE_PX
from .guided import open_coarse_edges
from .reproject import (MAX_INCIDENCE_DEG, MIN_DEPTH_RATIO, default_depth_ratio, needs_registration, plan_for,
                        plan_info, register_depth, reproject_depth, warmup)

__all__ = [
    "MAX_INCIDENCE_DEG", "MAX_PRIMITIVE_PX", "MIN_DEPTH_RATIO", "default_depth_ratio", "needs_registration",
    "open_coarse_edges", "plan_for", "plan_info", "register_depth", "reproject_depth", "warmup",
]
