"""The capture's blur of fitted maps (``polarbssrdf.inverse.observations.footprint``).

Kernel variances are checked against their definitions: a box of one pixel has variance 1/12,
a tent of half-width 1 has 1/6 (numerical integrals here, not the module's constants), and a
pixel of angular size 1/f at distance d tilted by theta spans d/f and d/(f cos theta).
"""

import numpy as np
import pytest


def _variance(kernel, x):
    weight = kernel(x)
    return float(np.sum(weight * x ** 2) / np.sum(weight))


def test_the_sampling_kernels_are_box_and_tent():
    from polarbssrdf.inverse.observations.footprint import (
        PIXEL_SAMPLING_VARIANCE_PX2,
        TEXTURE_FILTER_VARIANCE_TEXELS2,
        demosaicking_variance_px2,
    )

    x = np.linspace(-3, 3, 600001)
    box = _variance(lambda t: (np.abs(t) <= 0.5).astype(float), x)
    tent = _variance(lambda t: np.maximum(1 - np.abs(t), 0), x)
    assert PIXEL_SAMPLING_VARIANCE_PX2 == pytest.approx(box + tent, rel=1e-4)
    assert TEXTURE_FILTER_VARIANCE_TEXELS2 == pytest.approx(tent, rel=1e-4)
    # a period-2 mosaic's bilinear reach: a tent of half-width 2, less the sample's own tent
    wide = _variance(lambda t: np.maximum(1 - np.abs(t) / 2, 0), x)
    assert demosaicking_variance_px2(2) == pytest.approx(wide - tent, rel=1e-4)
    assert demosaicking_variance_px2(1) == 0.0


def test_a_tilted_pixel_spreads_along_its_tilt():
    from polarbssrdf.inverse.observations.footprint import pixel_footprint_variance_mm2

    # 600 mm away, f = 1200 px: a pixel spans 0.5 mm head-on
    head_on = pixel_footprint_variance_mm2(600.0, 1.0, 1200.0, 1.0)
    assert head_on == pytest.approx(0.25)
    # at 60 degrees it spans 1 mm along the tilt: the mean of 0.25 and 1 mm^2
    assert pixel_footprint_variance_mm2(600.0, 0.5, 1200.0, 1.0) == pytest.approx(0.625)
    assert pixel_footprint_variance_mm2(1200.0, 1.0, 1200.0, 0.25) == pytest.approx(0.25)

