"""Sensor layouts: the IMX250MZR/MYR patterns and the validation of layouts and sizes."""

import numpy as np
import pytest

from polarbssrdf.capture import (
    DEMOSAICKING_METHODS,
    IMX250MYR,
    IMX250MZR,
    SensorLayout,
    channel_name,
    demosaic,
    mosaic_images,
)


def test_monochrome_cell_is_90_45_over_135_0():
    assert IMX250MZR.period == (2, 2)
    assert IMX250MZR.colour_names == ("",) and not IMX250MZR.is_colour
    assert IMX250MZR.channel_names == ("I0", "I45", "I90", "I135")
    assert IMX250MZR.offsets(90) == ((0, 0),)
    assert IMX250MZR.offsets(45) == ((0, 1),)
    assert IMX250MZR.offsets(135) == ((1, 0),)
    assert IMX250MZR.offsets(0) == ((1, 1),)


def test_colour_cells_form_an_rggb_bayer_pattern():
    assert IMX250MYR.period == (4, 4)
    assert IMX250MYR.colour_names == ("R", "G", "B")
    assert IMX250MYR.channel_names[:3] == ("I0.R", "I0.G", "I0.B")
    assert len(IMX250MYR.channel_names) == 12
    assert IMX250MYR.offsets(90, "R") == ((0, 0),)
    assert IMX250MYR.offsets(0, "G") == ((1, 3), (3, 1))
    assert IMX250MYR.offsets(135, "B") == ((3, 2),)


def test_sample_masks_partition_the_sensor():
    for layout in (IMX250MZR, IMX250MYR):
        count = sum(layout.sample_mask((8, 12), a, c).astype(int)
                    for a in (0, 45, 90, 135) for c in layout.colour_names)
        assert np.all(count == 1)


def test_channel_names_follow_the_render_convention():
    assert channel_name(45) == "I45"
    assert channel_name(135, "G") == "I135.G"


@pytest.mark.parametrize("shape, message", [
    ((6, 8), "not a multiple"), ((8, 6), "not a multiple"), ((8,), "2-D"),
    ((8, 8, 3), "2-D"), ((0, 8), "empty")])
def test_sizes_must_be_multiples_of_the_period(shape, message):
    with pytest.raises(ValueError, match=message):
        IMX250MYR.check_shape(shape)
    IMX250MYR.check_shape((8, 12))


@pytest.mark.parametrize("angles, colours, message", [
    (((0, 45), (90, 30)), (("", ""), ("", "")), "analyser angles"),
    (((0, 45), (90, 90)), (("", ""), ("", "")), "no pixels with analyser angles"),
    (((0, 45), (90, 135)), (("", ""),), "shape"),
    (((0, 45), (90, 135)), (("R", "R"), ("", "")), "mixes"),
    ((), (), "non-empty"),
])
def test_invalid_layouts_are_rejected(angles, colours, message):
    with pytest.raises(ValueError, match=message):
        SensorLayout("bad", angles, colours)


def test_other_layouts_can_be_described_and_demosaicked():
    stripes = SensorLayout("1 x 4 stripes", ((0, 45, 90, 135),), (("",) * 4,))
    assert stripes.period == (1, 4) and stripes.offsets(90) == ((0, 2),)
    values = (1.0, 2.0, 3.0, 4.0)
    truth = {name: np.full((4, 8), v) for name, v in zip(stripes.channel_names, values)}
    for method in DEMOSAICKING_METHODS:
        estimate = demosaic(mosaic_images(truth, stripes), stripes, method)
        for name in stripes.channel_names:
            np.testing.assert_allclose(estimate[name], truth[name], atol=1e-6)
