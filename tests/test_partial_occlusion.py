"""Partial occlusion: a layer continued behind a blurred foreground is continued by what is seen beside it.

A small bright layer (a lamp or glint between a blurred foreground and a sharp background) must not be
copied over the whole width the foreground hides: the light it adds would come from nothing.
"""

from __future__ import annotations

import numpy as np
import pytest

from pcdof.reference import render as ref
from pcdof.renderer import render_layers_linear


def _scene(radiance):
    h, w = 48, 64
    lin = np.full((h, w, 3), 0.3, np.float32)
    coc = np.zeros((h, w), np.float32)  # background in focus
    coc[:, :30] = -24.0  # blurred foreground on the left
    lin[:, :30] = (0.6, 0.2, 0.2)
    coc[22:25, 30:33] = -4.0  # a 3 x 3 lamp between them, touching the foreground's edge
    lin[22:25, 30:33] = radiance
    return lin, coc


@pytest.mark.parametrize("radiance", [1.0, 50.0])
@pytest.mark.parametrize("renderer", ["fast", "reference"])
def test_small_layer_is_not_copied_behind_a_blurred_foreground(renderer, radiance):
    lin, coc = _scene(radiance)
    if renderer == "fast":
        out = render_layers_linear(lin, coc, quality="exact")[0]
    else:
        out = ref.render_layers_linear(lin, coc).astype(np.float32)
    # every source spreads its own light and nearer layers only take some away: no light from nothing
    assert float(out.sum()) <= 1.01 * float(lin.sum())
