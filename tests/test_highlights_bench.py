"""The wide benchmark's highlight tuning: the default rule, and reconstruction between the pipeline's stages."""

from __future__ import annotations

import numpy as np

from pcdof.bench import wide


def _tuned(label_gain_worst):
    return [{"highlights": h, "gain_db": g, "worst_db": w, "worst_edge_db": e} for h, g, w, e in label_gain_worst]


def test_rule_takes_the_largest_mean_gain_within_the_loss_bound():
    tuned = _tuned([({"method": "off"}, 0.0, 0.0, 0.0), ({"method": "gain", "gain": 4.0}, 2.2, -1.0, -1.4),
                    ({"method": "prior", "prior_max": 16.0}, 1.9, -0.1, -0.2),
                    ({"method": "prior", "prior_max": 8.0}, 1.4, 0.0, 0.0),
                    ({"method": "rim"}, 1.95, -0.1, -0.3)])  # within the bound overall, not in the edge band
    assert wide.choose_highlights(tuned) == {"method": "prior", "prior_max": 16.0}
    assert wide.choose_highlights(tuned, max_loss_db=2.0) == {"method": "gain", "gain": 4.0}
    assert wide.choose_highlights(tuned[:2]) == {"method": "off"}
    assert "picks: prior max 16" in wide.tuning_table([{**t, "psnr": 30.0, "psnr_edge": 25.0, "psnr_measured": 30.0,
                                                       "psnr_measured_edge": 25.0, "losses": 0, "cases": 9}
                                                      for t in tuned])


def test_reconstruction_between_stages_matches_the_pipeline():
    """A dict of reconstruction options (tuning) renders what the pipeline's highlights stage renders for the
    same setting, up to the 8-bit encoding of the pipeline's output."""
    from pcdof.synth.wide import generate_wide, lens_for_blur

    sf, spec = generate_wide("night", seed=7, color_size=(96, 72), depth_size=(96, 80), pixel_samples=1)
    lens = lens_for_blur(sf.depth_color_m, sf.rig.color.fx, spec.focus_m["near"], 12.0)
    off = wide.render_variant(wide.Variant(highlights="off"), sf, lens).astype(float)
    for dict_hl, value in (({"method": "prior", "prior_max": 16.0}, "auto"), ({"method": "gain", "gain": 3.0}, 3.0)):
        a = wide.render_variant(wide.Variant(highlights=dict_hl), sf, lens)
        b = wide.render_variant(wide.Variant(highlights=value), sf, lens)
        assert a.dtype == np.float32 and b.dtype == np.uint8
        assert np.abs(wide.encode_srgb8(a) * 255 - b).max() <= 1.0
        assert np.abs(b - off).max() > 20  # the highlights changed the render
