"""The render stage: depth of field from a registered, hole-filled RGB-D pair.

Two renderers with one signature, registered in :data:`METHODS` (:mod:`.methods`)::

    fn(color, depth_m, lens, *, fx, max_range_m, linear, quality, signed_coc, plan, border_most) -> (image, info)

``color`` is (H, W, 3) of any supported dtype, ``depth_m`` the registered and filled depth
(H, W) in metres; ``image`` has the dtype and shape of ``color``; ``info`` is a plain dict
describing the work done (which blur layers ran, what was skipped), used by the pipeline trace.

- :mod:`.physical`: the physical thin-lens renderer (default), built from
  :mod:`.classify` (layer classification), :mod:`.aperture` (aperture tables), :mod:`.scatter` (scatter
  kernels), :mod:`.uniform` (uniform-tile convolution), :mod:`.grids` (reduced-resolution grids),
  :mod:`.extend` (extension behind nearer layers), :mod:`.ownership` (ownership of hidden pixels),
  :mod:`.composite` (composite kernels), :mod:`.tiles` (the tile map), :mod:`.frame` (what the layers
  share), :mod:`.border` (what lies beyond the frame) and :mod:`.mixed` (mixed pixels at the edges of in-focus
  surfaces); :mod:`.serial` says when a kernel runs on one thread
- :mod:`.paper`: the seed paper's method
- :mod:`.reference`: the plain numpy specification the fast paths are tested against
"""

from ...plans import QUALITIES, UNIFORM_MIN_RADIUS_PX, check_quality
from .aperture import aperture_table
from .classify import LAYER_EDGES_PX, MIN_SOURCE_RADIUS_PX, SHARP_COC_PX
from .composite import copy_tiles
from .grids import resample_variance_px2, upsample_cells
from .methods import METHODS, check_method, render_image, warmup
from .paper import paper_lens_for, render_paper
from .physical import render_layers_linear, render_physical
from .tiles import TILE_PX, TileMap, classify_tiles
from .uniform import UNIFORM_BIN, UNIFORM_MAX_WASTE

__all__ = [
    "METHODS", "QUALITIES", "LAYER_EDGES_PX", "SHARP_COC_PX", "MIN_SOURCE_RADIUS_PX", "UNIFORM_BIN",
    "UNIFORM_MAX_WASTE", "UNIFORM_MIN_RADIUS_PX", "TILE_PX", "TileMap", "aperture_table", "check_method",
    "check_quality", "classify_tiles", "copy_tiles", "paper_lens_for", "render_image", "render_layers_linear",
    "render_paper", "render_physical", "resample_variance_px2", "upsample_cells", "warmup",
]
