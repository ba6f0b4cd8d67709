"""Lens settings a photographer names: an f-number in 35 mm terms, or a blur as a share of the image width.

pcdof's thin lens blurs a point at depth z into a disc of diameter (pixels)
``c(z) = A * fx * |1/d_f - 1/z|`` (A the aperture diameter, fx the photo's focal length in pixels,
d_f the focus distance). Two ways to choose A that need no knowledge of the phone's own optics:

* **An f-number in 35 mm terms** (:func:`equivalent_lens`): "make it look like a full-frame camera at
  f/1.4 with this photo's field of view". A full-frame lens with the same angle of view has the photo's
  35 mm equivalent focal length f35, so ``A = f35 / N``; the photo's fx (pixels) already holds its field
  of view, so the blur is the full-frame camera's at any image size.
* **A blur amount** (:class:`BlurShareLens`): "a far background blurs into discs this share of the
  image width". With z -> infinity, ``c = A * fx / d_f = share * W``, so ``A = share * W * d_f / fx``,
  recomputed whenever the focus moves. It needs no metric depth scale (scaling all depths by k scales
  d_f by k and 1/d_f - 1/z by 1/k): the choice for depth maps without units.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from .camera import Intrinsics
from .errors import LensError
from .lens import ThinLens

#: diagonal of the 36 x 24 mm frame, mm (35 mm equivalent focal lengths keep the diagonal angle of view)
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)


def _positive(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise LensError(f"{name} must be a finite number > 0; got {value!r}")
    return float(value)


def focal_35mm(camera: Intrinsics) -> float:
    """The 35 mm equivalent focal length (mm) of *camera*: ``fx * 43.27 / hypot(W, H)``."""
    if not isinstance(camera, Intrinsics):
        raise LensError(f"camera must be an Intrinsics; got {type(camera).__name__}")
    return camera.fx * FULL_FRAME_DIAGONAL_MM / math.hypot(camera.width, camera.height)


def equivalent_lens(lens: ThinLens, camera: Intrinsics, f_number_35mm: float) -> ThinLens:
    """*lens* with the aperture of a full-frame lens at *f_number_35mm* with *camera*'s field of view.

    Parameters
    ----------
    lens : ThinLens, its focus and aperture shape are kept
    camera : Intrinsics of the photo (its fx and size give the 35 mm equivalent focal length)
    f_number_35mm : float, the f-number N in 35 mm terms (> 0)

    Returns
    -------
    ThinLens with ``focal_length_mm = f35`` and ``f_number = N`` (aperture A = f35 / N)
    """
    if not isinstance(lens, ThinLens):
        raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
    n = _positive("f_number_35mm", f_number_35mm)
    return dataclasses.replace(lens, focal_length_mm=focal_35mm(camera), f_number=n)


@dataclass(frozen=True)
class BlurShareLens(ThinLens):
    """A thin lens whose aperture makes a far background blur into discs of ``blur_share`` of the image width.

    Parameters
    ----------
    blur_share : float, disc diameter at infinity / image width (0.02 = 2 %), in (0, 1]
    width_over_fx : float, image width / fx of the photo's camera (2 tan(horizontal half angle of view))
    (and :class:`~pcdof.lens.ThinLens`'s; ``f_number`` is derived: ``f / (blur_share * width_over_fx * d_f)``)
    """

    blur_share: float = 0.02
    width_over_fx: float = 1.0

    def __post_init__(self) -> None:
        share = _positive("blur_share", self.blur_share)
        if share > 1.0:
            raise LensError(f"blur_share must be at most 1 (the image width); got {share!r}")
        ratio = _positive("width_over_fx", self.width_over_fx)
        focus = _positive("focus_distance_m", self.focus_distance_m)
        focal = _positive("focal_length_mm", self.focal_length_mm)
        object.__setattr__(self, "f_number", focal * 1e-3 / (share * ratio * focus))
        super().__post_init__()

    @classmethod
    def for_camera(cls, lens: ThinLens, camera: Intrinsics, blur_share: float) -> "BlurShareLens":
        """*lens* (focus, aperture shape) as a BlurShareLens for the photo taken with *camera*."""
        if not isinstance(lens, ThinLens):
            raise LensError(f"lens must be a ThinLens; got {type(lens).__name__}")
        if not isinstance(camera, Intrinsics):
            raise LensError(f"camera must be an Intrinsics; got {type(camera).__name__}")
        fields = {f.name: getattr(lens, f.name) for f in dataclasses.fields(ThinLens)}
        return cls(**fields, blur_share=blur_share, width_over_fx=camera.width / camera.fx)
