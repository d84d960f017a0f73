"""Cross-camera gains from synthetic images of a white (Lambertian) reference sphere."""

import numpy as np
import pytest

from polarbssrdf.calibration import sphere_gains, sphere_statistic


def sphere_image(shape, centre, radius, gain, rng, noise=0.005, background=0.02, colour=(0.9, 1.0, 0.8)):
    """A coaxially lit Lambertian sphere: radiance ~ n . v = sqrt(1 - r^2 / R^2), per channel."""
    rows, columns = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    r2 = ((columns - centre[0]) ** 2 + (rows - centre[1]) ** 2) / radius ** 2
    shading = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    image = background + shading[..., None] * np.asarray(colour)[None, None, :]
    image = gain * image
    return image * (1.0 + noise * rng.standard_normal(image.shape))


def test_synthetic_gains_are_recovered_whatever_the_sphere_size_and_position():
    rng = np.random.default_rng(9)
    true_gains = {"cam0": np.array([1.0, 1.0, 1.0]), "cam1": np.array([1.23, 1.18, 1.31]),
                  "cam2": np.array([0.81, 0.86, 0.77]), "cam3": np.array([1.05, 0.97, 1.10])}
    layouts = {"cam0": ((320, 240), 90), "cam1": ((250, 260), 140), "cam2": ((400, 200), 60),
               "cam3": ((300, 250), 110)}
    images = {name: sphere_image((480, 640), *layouts[name], true_gains[name], rng) for name in true_gains}
    gains = sphere_gains(images)
    for name, truth in true_gains.items():
        np.testing.assert_allclose(gains[name], truth, rtol=0.01)
    # normalized images agree: the sphere's centre value is the same in every camera
    centres = [images[n][layouts[n][0][1], layouts[n][0][0]] / gains[n] for n in images]
    np.testing.assert_allclose(centres, centres[0][None].repeat(4, 0), rtol=0.03)


def test_gains_against_a_predicted_value_are_absolute():
    rng = np.random.default_rng(1)
    image = sphere_image((240, 320), (160, 120), 70, 2.0, rng, colour=(1.0, 1.0, 1.0), background=0.0)
    # the mean of sqrt(1 - r^2) over r < R/2 is (2/3)(1 - (3/4)^1.5) / (1/4) = 0.8453
    predicted = (2.0 / 3.0) * (1.0 - 0.75 ** 1.5) / 0.25
    gain = sphere_gains({"cam": image}, predicted=predicted)["cam"]
    np.testing.assert_allclose(gain, 2.0, rtol=0.01)
    assert sphere_statistic(image[..., 0]).shape == (1,)


def test_an_image_without_a_sphere_is_a_clear_error():
    with pytest.raises(ValueError, match="camera cam1: image has no bright pixels"):
        sphere_gains({"cam0": sphere_image((100, 100), (50, 50), 30, 1.0, np.random.default_rng(0)),
                      "cam1": np.zeros((100, 100))})
