"""The forward mosaic: every raw pixel is the right analyser/colour sample; bad inputs fail."""

import numpy as np
import pytest

from polarbssrdf.capture import IMX250MYR, IMX250MZR, mosaic_images

# Written out by hand, independently of SensorLayout: (row % 2, col % 2) -> analyser,
# and (row // 2 % 2, col // 2 % 2) -> colour of the IMX250MYR's RGGB cells.
ANGLE_OF_CELL_POSITION = {(0, 0): 90, (0, 1): 45, (1, 0): 135, (1, 1): 0}
COLOUR_OF_CELL = {(0, 0): "R", (0, 1): "G", (1, 0): "G", (1, 1): "B"}


def coded_images(layout, height, width):
    """Each channel's pixel value encodes (channel, row, column) uniquely."""
    y, x = np.mgrid[0:height, 0:width]
    return {name: 1e6 * (k + 1) + y * width + x for k, name in enumerate(layout.channel_names)}


@pytest.mark.parametrize("layout", [IMX250MZR, IMX250MYR], ids=lambda l: l.name)
def test_each_raw_pixel_is_its_analyser_and_colour_sample(layout):
    height, width = 8, 12
    images = coded_images(layout, height, width)
    raw = mosaic_images(images, layout)
    assert raw.shape == (height, width) and raw.dtype == np.float64
    for row in range(height):
        for col in range(width):
            angle = ANGLE_OF_CELL_POSITION[row % 2, col % 2]
            colour = COLOUR_OF_CELL[row // 2 % 2, col // 2 % 2] if layout.is_colour else ""
            name = f"I{angle}" + (f".{colour}" if colour else "")
            assert raw[row, col] == images[name][row, col], (row, col, name)


def test_extra_channels_are_ignored():
    images = coded_images(IMX250MZR, 4, 4)
    raw = mosaic_images({**images, "S0": np.full((4, 4), np.nan)}, IMX250MZR)
    assert np.all(np.isfinite(raw))


def _images(**changes):
    images = {name: np.ones((8, 8)) for name in IMX250MZR.channel_names}
    images.update(changes)
    return {k: v for k, v in images.items() if v is not None}


@pytest.mark.parametrize("images, message", [
    (_images(I45=None), r"lack channels \['I45'\]"),
    (_images(I90=np.ones((8, 8, 3))), "I90 must be a 2-D"),
    (_images(I135=np.ones((8, 4))), "I135 has shape"),
    (_images(I0=np.where(np.eye(8) > 0, np.nan, 1.0)), "I0 has 8 NaN"),
    (_images(I45=-np.ones((8, 8))), "I45 has negative intensities"),
    ({name: np.ones((6, 7)) for name in IMX250MZR.channel_names}, "not a multiple"),
    (_images(I0=np.full((8, 8), "a")), "real numbers"),
])
def test_bad_analyser_images_name_the_problem(images, message):
    with pytest.raises(ValueError, match=message):
        mosaic_images(images, IMX250MZR)


def test_colour_sizes_must_be_multiples_of_four():
    images = {name: np.ones((6, 8)) for name in IMX250MYR.channel_names}
    with pytest.raises(ValueError, match="6 x 8 is not a multiple of the 4 x 4 period"):
        mosaic_images(images, IMX250MYR)
