"""Demosaicking: exact on constant fields and at the samples, accurate on smooth scenes,
and the intensity-guided residual interpolation beats bilinear on edges."""

import numpy as np
import pytest

from polarbssrdf.capture import (
    DEMOSAICKING_METHODS,
    IMX250MYR,
    IMX250MZR,
    demosaic,
    demosaic_residual,
    intensity_guides,
    mosaic_images,
)

LAYOUTS = [IMX250MZR, IMX250MYR]
layouts = pytest.mark.parametrize("layout", LAYOUTS, ids=lambda l: l.name)
methods = pytest.mark.parametrize("method", DEMOSAICKING_METHODS)


@layouts
@methods
def test_constant_fields_are_exact_everywhere(layout, method):
    # A different constant per channel: a uniformly polarized, coloured field.
    values = np.linspace(0.2, 3.0, len(layout.channel_names))
    truth = {name: np.full((16, 24), v) for name, v in zip(layout.channel_names, values)}
    estimate = demosaic(mosaic_images(truth, layout), layout, method)
    assert set(estimate) == set(layout.channel_names)
    for name in layout.channel_names:
        assert estimate[name].dtype == np.float64
        np.testing.assert_allclose(estimate[name], truth[name], rtol=0, atol=1e-6, err_msg=name)


@layouts
@methods
def test_samples_are_kept(layout, method, kit):
    truth = kit.analyser_images(kit.disk(size=32), layout)
    raw = mosaic_images(truth, layout)
    estimate = demosaic(raw, layout, method)
    for angle in (0, 45, 90, 135):
        for colour in layout.colour_names:
            mask = layout.sample_mask(raw.shape, angle, colour)
            name = f"I{angle}" + (f".{colour}" if colour else "")
            assert np.array_equal(estimate[name][mask], raw[mask])


@layouts
@methods
def test_smooth_scenes_have_small_errors(layout, method, kit):
    truth = kit.analyser_images(kit.smooth(size=64), layout)
    estimate = demosaic(mosaic_images(truth, layout), layout, method)
    margin = layout.period[0]
    inner = (slice(margin, -margin), slice(margin, -margin))
    # S0 is about 1.3 at most; bilinear's error is h^2 f''/8 with h the sample spacing.
    bound = 0.01 if layout is IMX250MZR else 0.03
    for name in layout.channel_names:
        assert np.abs(estimate[name] - truth[name])[inner].max() < bound, name
        # Borders extrapolate a constant, so they are looser but bounded.
        assert np.abs(estimate[name] - truth[name]).max() < 0.1, name
    for psnr, aolp_error in kit.errors(truth, estimate, layout, margin).values():
        assert psnr > 50 and aolp_error < 0.5


@pytest.mark.parametrize("scene", ["disk", "sphere"])
@layouts
def test_residual_interpolation_beats_bilinear_on_edges(scene, layout, kit):
    """S0 PSNR and mean AoLP error (DoLP > 0.1), 128 x 128, 4-pixel margin.

    Measured (bilinear -> residual): disk mono 31.9 -> 34.4 dB, 0.99 -> 0.83 deg;
    sphere mono 37.6 -> 39.2 dB, 0.68 -> 0.61 deg; disk colour G 28.3 -> 29.8 dB,
    1.71 -> 1.37 deg; sphere colour G 34.4 -> 35.8 dB, 0.88 -> 0.78 deg.
    """
    truth = kit.analyser_images(getattr(kit, scene)(size=128), layout)
    raw = mosaic_images(truth, layout)
    bilinear = kit.errors(truth, demosaic(raw, layout, "bilinear"), layout, 4)
    residual = kit.errors(truth, demosaic(raw, layout, "residual"), layout, 4)
    for colour in layout.colour_names:
        (psnr_b, aolp_b), (psnr_r, aolp_r) = bilinear[colour], residual[colour]
        assert psnr_r > psnr_b + 0.5, (colour, psnr_b, psnr_r)
        assert aolp_r < 0.95 * aolp_b, (colour, aolp_b, aolp_r)


def test_monochrome_guide_is_the_3x3_intensity_filter(kit):
    truth = kit.analyser_images(kit.disk(size=32), IMX250MZR)
    raw = mosaic_images(truth, IMX250MZR)
    kernel = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]]) / 16
    inner = np.array([[np.sum(kernel * raw[r - 1:r + 2, c - 1:c + 2]) for c in range(1, 31)]
                      for r in range(1, 31)])
    np.testing.assert_allclose(intensity_guides(raw, IMX250MZR)[""][1:-1, 1:-1], inner, atol=1e-12)


def test_more_iterations_sharpen_the_disk(kit):
    truth = kit.analyser_images(kit.disk(size=64), IMX250MZR)
    raw = mosaic_images(truth, IMX250MZR)
    once = kit.errors(truth, demosaic_residual(raw, IMX250MZR), IMX250MZR, 4)[""]
    twice = kit.errors(truth, demosaic_residual(raw, IMX250MZR, iterations=2), IMX250MZR, 4)[""]
    assert twice[0] > once[0]


def test_demosaicking_is_linear_in_scale(kit):
    truth = kit.analyser_images(kit.sphere(size=32), IMX250MYR)
    raw = mosaic_images(truth, IMX250MYR)
    one, scaled = demosaic(raw, IMX250MYR), demosaic(1000.0 * raw, IMX250MYR)
    for name in one:
        np.testing.assert_allclose(scaled[name], 1000.0 * one[name], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("raw, layout, options, message", [
    (np.ones((6, 8)), IMX250MYR, {}, "6 x 8 is not a multiple of the 4 x 4 period"),
    (np.ones((7, 8)), IMX250MZR, {}, "not a multiple"),
    (np.ones((8, 8, 3)), IMX250MZR, {}, "2-D"),
    (np.where(np.eye(8) > 0, np.nan, 1.0), IMX250MZR, {}, "8 NaN"),
    (np.ones((8, 8)), IMX250MZR, {"method": "nearest"}, "unknown demosaicking method"),
    (np.ones((8, 8)), IMX250MZR, {"eps": -1.0}, "eps"),
    (np.ones((8, 8)), IMX250MZR, {"radius": 0}, "radius"),
    (np.ones((8, 8)), IMX250MZR, {"iterations": 0}, "iterations"),
    (np.ones((8, 8)), IMX250MZR, {"method": "bilinear", "eps": 1.0}, "no options"),
])
def test_bad_raw_inputs_name_the_problem(raw, layout, options, message):
    with pytest.raises(ValueError, match=message):
        demosaic(raw, layout, **options)
