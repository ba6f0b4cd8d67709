"""One frame's state in the browser viewer: the depth computed once, the lens, and the renders.

The registered and filled depth are computed once (:func:`pcdof.viewer.prepare_frame`); a lens change
only recomputes the circle of confusion and the render (:func:`pcdof.viewer.render_preview`), on a
downscaled copy while a slider is dragged (:func:`pcdof.viewer.downscale_for_preview`) and at full
resolution when it is released.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ...camera import Intrinsics, check_color
from ...errors import InputError, LensError
from ...lens import ThinLens, positive_number
from ...focus import depth_at
from ..scene import downscale_for_preview, lens_numbers, render_preview

#: Largest side of the preview rendered while a slider is dragged, pixels.
DRAFT_MAX_SIDE = 240
#: Lens fields a browser control may set, with their checks.
LENS_FIELDS = ("focus_distance_m", "f_number", "focal_length_mm", "aperture_blades")


class ViewSession:
    """The lens and the renders of one frame whose depth is registered and filled.

    Parameters
    ----------
    color : (H, W, 3) RGB ndarray, the colour image
    registered_m, filled_m : (H, W) float32 ndarrays, metres, colour camera grid (0 = unknown in the first)
    intrinsics : Intrinsics, of the colour camera
    lens : ThinLens, the starting lens
    coc_limit_px : float, acceptable circle of confusion, pixels
    method : a key of :data:`pcdof.stages.render.METHODS`
    draft_max_side : int, largest side of the draft preview, pixels
    options : optional RenderOptions whose method, quality, linear and highlights the renders use
        (instead of *method*; its lens is replaced by the session's current one)

    Attributes
    ----------
    lens : ThinLens, current lens
    counts : dict, renders done so far: ``{"draft": n, "full": n}``
    """

    def __init__(self, color, registered_m, filled_m, intrinsics: Intrinsics, lens: ThinLens, *,
                 coc_limit_px: float = 1.0, method: str = "physical", draft_max_side: int = DRAFT_MAX_SIDE,
                 options=None):
        if not isinstance(intrinsics, Intrinsics):
            raise InputError(f"intrinsics must be an Intrinsics; got {type(intrinsics).__name__}")
        if not isinstance(lens, ThinLens):
            raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
        self.color = check_color(color, intrinsics.shape)
        self.registered_m = np.asarray(registered_m, np.float32)
        self.filled_m = np.asarray(filled_m, np.float32)
        for name, depth in (("registered_m", self.registered_m), ("filled_m", self.filled_m)):
            if depth.shape != intrinsics.shape:
                raise InputError(f"{name} must be (H, W) = {intrinsics.shape}; got {depth.shape}")
        known = self.filled_m[np.isfinite(self.filled_m) & (self.filled_m > 0)]
        if known.size == 0:
            raise InputError("filled_m has no known depth (all values are 0, negative or not finite)")
        self.z_min_m, self.z_max_m = float(known.min()), float(known.max())
        self.intrinsics = intrinsics
        self.lens = lens
        self.coc_limit_px = positive_number("coc_limit_px", coc_limit_px)
        self.method = method
        self.options = options
        self._draft_inputs = downscale_for_preview(self.color, self.filled_m, intrinsics.fx, max_side=draft_max_side)
        self._full = None  # (lens, image) of the last full-resolution render
        self.counts = {"draft": 0, "full": 0}

    def set_lens(self, **changes) -> ThinLens:
        """Change fields of the lens (:data:`LENS_FIELDS`); returns the new lens."""
        unknown = set(changes) - set(LENS_FIELDS)
        if unknown:
            raise InputError(f"lens fields must be among {list(LENS_FIELDS)}; got {sorted(unknown)}")
        if "aperture_blades" in changes:
            changes["aperture_blades"] = int(changes["aperture_blades"])
        self.lens = dataclasses.replace(self.lens, **changes)  # ThinLens checks every field
        return self.lens

    @property
    def numbers(self) -> dict:
        """:func:`pcdof.viewer.lens_numbers` of the current lens over this frame's depths."""
        return lens_numbers(self.lens, self.intrinsics, z_min_m=self.z_min_m, z_max_m=self.z_max_m,
                            coc_limit_px=self.coc_limit_px)

    def render(self, *, draft: bool) -> np.ndarray:
        """The photograph for the current lens: (h, w, 3) uint8 sRGB, downscaled when *draft*, else full size.

        The full-resolution render is kept for the current lens, so asking again (the download) costs nothing.
        """
        if draft:
            small_color, small_depth, small_fx = self._draft_inputs
            self.counts["draft"] += 1
            return render_preview(small_color, small_depth, self.lens, small_fx, method=self.method,
                                  options=self.options)
        if self._full is None or self._full[0] != self.lens:
            self._full = (self.lens, render_preview(self.color, self.filled_m, self.lens, self.intrinsics.fx,
                                                    method=self.method, options=self.options))
            self.counts["full"] += 1
        return self._full[1]

    def depth_at(self, u: float, v: float) -> float:
        """Robust depth at colour pixel (u, v), metres (:func:`pcdof.focus.depth_at`)."""
        return depth_at(self.registered_m, self.filled_m, u, v)

    def depth_at_fraction(self, x_frac: float, y_frac: float) -> float:
        """Depth at the point a fraction (x_frac, y_frac) of the image's width and height from its top-left edge."""
        for name, value in (("x_frac", x_frac), ("y_frac", y_frac)):
            if not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
                raise InputError(f"{name} must be a fraction in [0, 1] of the image; got {value!r}")
        w, h = self.intrinsics.width, self.intrinsics.height
        # pixel centres are integers: the left edge is at -0.5, the right one at W - 0.5
        return self.depth_at(min(x_frac * w - 0.5, w - 1.0), min(y_frac * h - 0.5, h - 1.0))
