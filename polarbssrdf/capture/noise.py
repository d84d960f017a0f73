"""Photon shot noise, read noise and quantization of a sensor (EMVA 1288-style linear model).

Units. The input is the ideal mosaic in linear radiance units ``L`` (whatever
the renderer or the analyser images use). One exposure turns it into

    mean photo-electrons  mu_e = electrons_per_radiance * L
    electrons             e    = min(Poisson(mu_e), full_well_electrons)
    read-out              v    = e + Normal(0, read_noise_electrons)
    digital number (DN)   DN   = clip(round(gain * v + black_level_dn), 0, 2^bit_depth - 1)

``gain`` is in DN per electron; by default the full well fills the ADC range,
``gain = (2^bit_depth - 1) / full_well_electrons``. Below saturation the
mean and variance of DN are (EMVA Standard 1288, release 4.0, eq. 9 and 11)

    E[DN]   = gain * mu_e + black_level_dn
    Var[DN] = gain^2 (mu_e + read_noise_electrons^2) + 1/12

(the last term is the variance of uniform rounding). The defaults are of the
order of IMX250-class sensors: full well about 10 ke-, read noise a few e-,
12-bit output.

Saturation: charge saturates at the full well, the ADC at ``2^bit_depth - 1``.
With the default gain and no black level the full well maps to exactly 4095,
so read noise dithers saturated pixels down to about ``4095 - 3 gain sigma``;
any positive black level (as real cameras use) makes the ADC clip first and
saturated pixels read exactly 4095.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SensorNoise", "expected_raw_mean", "expected_raw_variance", "radiance_from_raw",
           "simulate_raw"]


@dataclass(frozen=True)
class SensorNoise:
    """Linear sensor model: exposure, shot noise, read noise, ADC.

    Parameters
    ----------
    electrons_per_radiance:
        Mean photo-electrons collected per unit of input radiance in one
        exposure (quantum efficiency x exposure time x pixel etendue), e-/L.
    full_well_electrons:
        Charge capacity of a pixel, electrons; photo-electrons saturate there.
    read_noise_electrons:
        Standard deviation of the Gaussian read noise, electrons.
    bit_depth:
        ADC resolution in bits; DN lie in ``[0, 2^bit_depth - 1]``.
    black_level_dn:
        Offset added before quantization, DN (keeps read noise of dark
        pixels from being clipped at 0).
    gain_dn_per_electron:
        Conversion gain, DN per electron; ``None`` maps the full well to the
        largest DN.
    """

    electrons_per_radiance: float
    full_well_electrons: float = 10500.0
    read_noise_electrons: float = 2.5
    bit_depth: int = 12
    black_level_dn: float = 0.0
    gain_dn_per_electron: float | None = None

    def __post_init__(self) -> None:
        positive = {"electrons_per_radiance": self.electrons_per_radiance,
                    "full_well_electrons": self.full_well_electrons}
        if self.gain_dn_per_electron is not None:
            positive["gain_dn_per_electron"] = self.gain_dn_per_electron
        for name, value in positive.items():
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        for name, value in {"read_noise_electrons": self.read_noise_electrons,
                            "black_level_dn": self.black_level_dn}.items():
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative finite number, got {value!r}")
        if not (isinstance(self.bit_depth, int) and 1 <= self.bit_depth <= 16):
            raise ValueError(f"bit_depth must be an integer in 1..16, got {self.bit_depth!r}")

    @property
    def max_dn(self) -> int:
        """Largest digital number, ``2^bit_depth - 1`` (4095 for 12 bits)."""
        return 2 ** self.bit_depth - 1

    @property
    def gain(self) -> float:
        """Conversion gain in DN per electron."""
        if self.gain_dn_per_electron is not None:
            return float(self.gain_dn_per_electron)
        return self.max_dn / self.full_well_electrons


def _check_radiance(radiance) -> np.ndarray:
    values = np.asarray(radiance, dtype=np.float64)
    if values.ndim != 2:
        raise ValueError(f"the ideal mosaic must be a 2-D H x W array, got shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"the ideal mosaic has {np.count_nonzero(~np.isfinite(values))} "
                         "NaN or infinite values")
    if np.any(values < 0):
        raise ValueError(f"the ideal mosaic has negative intensities (minimum {values.min():g})")
    return values


def expected_raw_mean(radiance, noise: SensorNoise) -> np.ndarray:
    """Mean DN of a pixel of ``radiance`` below saturation: ``gain * mu_e + black_level``."""
    electrons = noise.electrons_per_radiance * np.asarray(radiance, dtype=np.float64)
    return noise.gain * electrons + noise.black_level_dn


def expected_raw_variance(radiance, noise: SensorNoise) -> np.ndarray:
    """DN variance below saturation: ``gain^2 (mu_e + read_noise^2) + 1/12`` (DN^2)."""
    electrons = noise.electrons_per_radiance * np.asarray(radiance, float)
    return noise.gain ** 2 * (electrons + noise.read_noise_electrons ** 2) + 1.0 / 12.0


def simulate_raw(radiance, noise: SensorNoise, rng: np.random.Generator) -> np.ndarray:
    """One noisy, quantized exposure of an ideal mosaic.

    Parameters
    ----------
    radiance:
        H x W ideal mosaic in linear radiance units, non-negative and finite
        (:func:`polarbssrdf.capture.mosaic.mosaic_images`).
    noise:
        The sensor model.
    rng:
        A seeded ``numpy.random.Generator``; the same seed gives the same raw.

    Returns
    -------
    numpy.ndarray
        H x W ``uint16`` digital numbers in ``[0, noise.max_dn]``.
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    values = _check_radiance(radiance)
    electrons = rng.poisson(noise.electrons_per_radiance * values).astype(np.float64)
    electrons = np.minimum(electrons, noise.full_well_electrons)
    electrons += rng.normal(0.0, noise.read_noise_electrons, size=values.shape)
    digital = np.rint(noise.gain * electrons + noise.black_level_dn)
    return np.clip(digital, 0, noise.max_dn).astype(np.uint16)


def radiance_from_raw(raw, noise: SensorNoise) -> np.ndarray:
    """Invert the mean response: ``(DN - black_level) / (gain * electrons_per_radiance)``.

    Returns float64 radiance in the input units of :func:`simulate_raw`;
    noise can make dark pixels slightly negative, which is kept (clipping
    would bias the mean). Saturated pixels (``DN == max_dn``) are not flagged
    here; compare ``raw`` with ``noise.max_dn`` for that.
    """
    values = np.asarray(raw)
    if values.ndim != 2:
        raise ValueError(f"raw must be a 2-D H x W array, got shape {values.shape}")
    values = values.astype(np.float64)
    if not np.all(np.isfinite(values)):
        raise ValueError("raw has NaN or infinite values")
    return (values - noise.black_level_dn) / (noise.gain * noise.electrons_per_radiance)
