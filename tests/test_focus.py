"""The focus rule (pcdof.focus): one resolution for the CLI, batch, viewers and API."""

import numpy as np
import pytest

from pcdof import ThinLens
from pcdof.errors import InputError
from pcdof.focus import CENTRE, centre_pixel, describe, focus_pixel, measured_depth, parse_focus_at, resolve_lens
from pcdof.options import RenderOptions

LENS = ThinLens(focal_length_mm=50, f_number=2, focus_distance_m=1.0)


def test_parse_accepts_pixels_centre_and_none():
    assert parse_focus_at(None) is None
    assert parse_focus_at("Centre") == CENTRE and parse_focus_at("center") == CENTRE
    assert parse_focus_at((3, 4.5)) == (3.0, 4.5)
    for bad in ("middle", (1,), (1, float("nan")), "1,2"):
        with pytest.raises(InputError, match="focus_at"):
            parse_focus_at(bad)


def test_centre_pixel_of_even_and_odd_sizes():
    assert centre_pixel(640, 480) == (319.5, 239.5)
    assert focus_pixel(CENTRE, 5, 3) == (2.0, 1.0)
    assert focus_pixel(None, 5, 3) is None


def test_resolve_lens_measures_the_registered_depth_and_falls_back_to_the_filled():
    filled = np.full((31, 41), 3.0, np.float32)
    registered = np.zeros_like(filled)
    registered[10:21, 15:26] = 2.0  # a measured patch around the centre (20, 15)
    assert resolve_lens(LENS, CENTRE, registered, filled).focus_distance_m == pytest.approx(2.0)
    # nothing measured: the filled depth decides
    assert resolve_lens(LENS, (2, 2), np.zeros_like(filled), filled).focus_distance_m == pytest.approx(3.0)
    assert measured_depth(np.zeros_like(filled), filled) is filled
    assert resolve_lens(LENS, None, registered, filled) is LENS  # the lens's own distance


def test_options_keep_centre_and_describe_it():
    options = RenderOptions(LENS, focus_at="centre")
    assert options.focus_at == CENTRE and options.to_dict()["focus_at"] == CENTRE
    assert describe(CENTRE) == "depth at the image centre"
    assert describe((1, 2)) == "depth at pixel 1,2"
    assert describe(None) == "the lens's focus distance"
