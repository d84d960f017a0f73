"""Stokes, DoLP, AoLP and separations from analyser images, and a noisy end-to-end capture."""

import numpy as np
import pytest

from polarbssrdf.capture import (
    IMX250MYR,
    IMX250MZR,
    PRODUCT_NAMES,
    SensorNoise,
    demosaic,
    mosaic_images,
    polarization_products,
    radiance_from_raw,
    simulate_raw,
)


def test_plus_45_degree_light_follows_the_design_conventions(kit):
    stokes = kit.linear_stokes(np.full((4, 4), 2.0), 0.5, 45.0)
    images = kit.analyser_images(stokes, IMX250MZR)
    products = polarization_products(images, IMX250MZR)
    assert set(products) == set(PRODUCT_NAMES)
    assert np.all(products["S2"] > 0) and np.all(images["I45"] > images["I135"])
    np.testing.assert_allclose(products["AoLP"], np.pi / 4)
    np.testing.assert_allclose(products["DoLP"], 0.5)
    np.testing.assert_allclose(products["I_zeta"], -products["S2"])
    np.testing.assert_allclose(products["I_s"], products["S1"], atol=1e-15)
    np.testing.assert_allclose(products["I_sss"], 2 * images["I90"])


def test_colour_products_carry_the_colour_suffix(kit):
    images = kit.analyser_images(kit.smooth(size=16), IMX250MYR)
    products = polarization_products(images, IMX250MYR)
    assert set(products) == {f"{name}.{c}" for name in PRODUCT_NAMES for c in "RGB"}
    np.testing.assert_allclose(products["S0.G"], images["I0.G"] + images["I90.G"])


def test_products_reject_missing_channels():
    with pytest.raises(ValueError, match="lack channels"):
        polarization_products({"I0": np.ones((2, 2))}, IMX250MZR)


def test_a_noisy_capture_recovers_dolp_and_aolp(kit):
    size = 64
    truth = kit.analyser_images(kit.smooth(size=size), IMX250MZR)
    noise = SensorNoise(electrons_per_radiance=4000.0, black_level_dn=64.0)
    raw = simulate_raw(mosaic_images(truth, IMX250MZR), noise, np.random.default_rng(5))
    estimate = demosaic(radiance_from_raw(raw, noise), IMX250MZR, "residual")
    got = polarization_products(estimate, IMX250MZR)
    want = polarization_products(truth, IMX250MZR)
    inner = (slice(2, -2), slice(2, -2))
    # About 4000 e- per pixel (1.6% shot noise): measured DoLP error 0.01, AoLP 1.2 deg.
    assert np.abs(got["DoLP"] - want["DoLP"])[inner].mean() < 0.02
    aolp_error = np.abs((got["AoLP"] - want["AoLP"] + np.pi / 2) % np.pi - np.pi / 2)
    assert np.rad2deg(aolp_error[inner].mean()) < 2.0
