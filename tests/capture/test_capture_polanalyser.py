"""Cross-check of bilinear demosaicking against polanalyser (MIT), when it is installed.

polanalyser runs OpenCV's Bayer demosaicking on uint16 data, so its output is
rounded to whole DN (tolerance 0.5 DN), and OpenCV fills the outermost row and
column differently from our renormalized weights: the comparison skips them.
"""

import numpy as np
import pytest

from polarbssrdf.capture import IMX250MZR, demosaic_bilinear

polanalyser = pytest.importorskip("polanalyser")


def test_bilinear_matches_polanalyser_inside_a_one_pixel_border():
    raw = np.random.default_rng(11).integers(0, 4096, (32, 48)).astype(np.uint16)
    theirs = polanalyser.demosaicing(raw, polanalyser.COLOR_PolarMono)
    ours = demosaic_bilinear(raw, IMX250MZR)
    for angle, image in zip((0, 45, 90, 135), theirs):
        difference = np.abs(image.astype(np.float64) - ours[f"I{angle}"])[1:-1, 1:-1]
        assert difference.max() <= 0.5 + 1e-9, angle
