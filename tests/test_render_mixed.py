"""Mixed pixels at the edges of in-focus surfaces (:mod:`pcdof.stages.render.mixed`): the compiled step against its
plain reference, an analytic picket, and the cases where nothing may change."""

from __future__ import annotations

import numpy as np
import pytest

from pcdof.lens import ThinLens
from pcdof.stages.render import mixed
from pcdof.stages.render.mixed import mix_edges
from pcdof.stages.render.reference import mixed_edges


def _random_case(rng):
    h, w, nc = int(rng.integers(3, 40)), int(rng.integers(3, 40)), int(rng.choice([1, 3, 4]))
    b = int(rng.integers(0, 4))
    z = (np.where(rng.random((h, w)) < 0.3, 1.0, 3.0) * (1 + 0.02 * rng.random((h, w)))).astype(np.float32)
    z[rng.random((h, w)) < 0.05] = np.nan
    coc = np.where(z < 2, rng.random((h, w)) * 0.9, 2.5 + rng.random((h, w)) * 10).astype(np.float32)
    coc *= np.where(rng.random((h, w)) < 0.5, 1, -1).astype(np.float32)
    lin = rng.random((h + 2 * b, w + 2 * b, nc)).astype(np.float32)
    # some pixels of the far surface made mixes of their neighbours, so that the rule has work to do
    inner = lin[b:b + h, b:b + w]
    for y, x in zip(rng.integers(1, h - 1, 20), rng.integers(1, w - 1, 20)):
        a = rng.random()
        inner[y, x] = a * inner[y, x + 1] + (1 - a) * inner[y, x - 1]
    return lin, b, z, coc, rng.random((h, w, nc)).astype(np.float32)


def test_the_compiled_step_is_its_plain_reference():
    rng = np.random.default_rng(0)
    mixes = 0
    for _ in range(40):
        lin, b, z, coc, out = _random_case(rng)
        want = mixed_edges(out, lin[b:lin.shape[0] - b, b:lin.shape[1] - b], z, coc)
        got = out.copy()
        n = mix_edges(got, lin, z, coc, b)
        np.testing.assert_allclose(got, want, atol=1e-6)
        assert n == np.count_nonzero(np.any(want != out, axis=-1))
        mixes += n
    assert mixes > 100  # the cases took the rule's every branch many times


def _picket(share: float):
    """A grey wall (0.2) at 3 m, blurred by 9 px; a white picket (0.9) at 1 m in columns 4-5, in focus; column 6
    carries the wall's depth and *share* of the picket's colour; the render the layers left: the wall blurred (0.3).
    Returns (depth, signed CoC, linear colour, render), 5 x 12."""
    h, w = 5, 12
    z = np.full((h, w), 3.0, np.float32)
    z[:, 4:6] = 1.0
    coc = np.where(z < 2, 0.2, 9.0).astype(np.float32)
    lin = np.full((h, w, 3), 0.2, np.float32)
    lin[:, 4:6] = 0.9
    lin[:, 6] = share * 0.9 + (1 - share) * 0.2
    return z, coc, lin, np.full((h, w, 3), 0.3, np.float32)


def test_a_pickets_edge_column_is_rendered_as_its_share_of_the_picket():
    """A grey wall (0.2) at 3 m, blurred; a white picket (0.9) at 1 m, in focus, whose right edge column carries the
    wall's depth and 3/4 of the picket's colour: that column becomes 3/4 picket over 1/4 of what the layers gave."""
    z, coc, lin, out = _picket(0.75)
    got = out.copy()
    assert mix_edges(got, lin, z, coc) == z.shape[0]
    np.testing.assert_allclose(got[:, 6], 0.75 * 0.9 + 0.25 * 0.3, atol=1e-6)
    np.testing.assert_array_equal(np.delete(got, 6, axis=1), np.delete(out, 6, axis=1))
    # a whole picket column (share 1) keeps its own colour, sharp
    lin[:, 6] = 0.9
    got = out.copy()
    mix_edges(got, lin, z, coc)
    np.testing.assert_allclose(got[:, 6], 0.9)


@pytest.mark.parametrize("change", ["blurred neighbour", "same depth", "colour beyond the picket's", "low contrast",
                                    "off the segment", "wall in focus", "unknown depth"])
def test_nothing_changes_where_the_pixel_is_not_such_a_mix(change):
    z, coc, lin, out = _picket(0.5)
    if change == "blurred neighbour":
        coc[:, 4:6] = 1.5
    elif change == "same depth":
        z[:, 4:6] = 2.8
    elif change == "colour beyond the picket's":
        lin[:, 6] = 1.2
    elif change == "low contrast":
        lin[:, 4:6] = 0.22
        lin[:, 6] = 0.21
    elif change == "off the segment":
        lin[:, 6] = (0.55, 0.3, 0.8)
    elif change == "wall in focus":
        coc[z > 2] = 1.5
    elif change == "unknown depth":
        z[:, 6] = np.nan
    got = out.copy()
    assert mix_edges(got, lin, z, coc) == 0
    np.testing.assert_array_equal(got, out)


def test_the_renderer_mixes_a_pickets_edge_and_says_how_many():
    from pcdof.stages.render import render_image

    h, w = 40, 64
    z = np.full((h, w), 3.0, np.float32)
    z[:, 30:33] = 1.0
    color = np.full((h, w, 3), 60, np.uint8)
    color[:, 30:34] = 230  # the picket is a column wider in colour than in depth
    lens = ThinLens(focal_length_mm=50.0, f_number=1.4, focus_distance_m=1.0)
    image, info = render_image(color, z, lens, fx=500.0)
    assert info["mixed_edge_pixels"] == h
    assert np.all(image[:, 33] == 230)  # sharp, its own colour, not the blurred wall's
    assert mixed.MAX_SHARE >= 1.0


def test_the_share_is_taken_from_the_colours_as_seen_and_the_light_from_the_estimate():
    """A picket that clipped (the highlights stage raised it to 5, above white): its edge column, 3/4 picket as the
    camera saw it (white), is 3/4 of the picket's estimated light over 1/4 of the blurred wall."""
    h, w = 4, 10
    z = np.full((h, w), 3.0, np.float32)
    z[:, 3:5] = 1.0
    coc = np.where(z < 2, 0.1, 7.0).astype(np.float32)
    lin = np.full((h, w, 3), 0.2, np.float32)
    lin[:, 3:5] = 5.0
    lin[:, 5] = 0.75 * 1.0 + 0.25 * 0.2
    out = np.full((h, w, 3), 0.4, np.float32)
    got = out.copy()
    assert mix_edges(got, lin, z, coc) == h
    np.testing.assert_allclose(got[:, 5], 0.75 * 5.0 + 0.25 * 0.4, rtol=1e-6)
    np.testing.assert_allclose(mixed_edges(out, lin, z, coc), got, rtol=1e-6)


@pytest.mark.parametrize("args, name", [
    ((np.zeros((4, 5, 3), np.float64), np.zeros((4, 5, 3), np.float32), np.ones((4, 5), np.float32),
      np.ones((4, 5), np.float32)), "out"),
    ((np.zeros((4, 5, 3), np.float32), np.zeros((4, 5, 1), np.float32), np.ones((4, 5), np.float32),
      np.ones((4, 5), np.float32)), "lin"),
    ((np.zeros((4, 5, 3), np.float32), np.zeros((4, 5, 3), np.float32), np.ones((5, 4), np.float32),
      np.ones((4, 5), np.float32)), "depth_m"),
    ((np.zeros((4, 5, 3), np.float32), np.zeros((4, 5, 3), np.float32), np.ones((4, 5), np.float32),
      np.ones((4, 5), np.float64)), "signed_coc"),
])
def test_bad_arguments_are_refused_naming_them(args, name):
    from pcdof.errors import InputError

    with pytest.raises(InputError, match=f"^{name} must be"):
        mix_edges(*args)
    with pytest.raises(InputError, match="^border must be an integer >= 0"):
        mix_edges(np.zeros((4, 5, 3), np.float32), np.zeros((4, 5, 3), np.float32), np.ones((4, 5), np.float32),
                  np.ones((4, 5), np.float32), -1)
