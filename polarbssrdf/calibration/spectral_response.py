"""Camera spectral response from narrow-band captures; filter transmittance; bands.

Supplement section 3.2: a white Spectralon target is lit through a liquid
crystal tunable filter every 10 nm over 420-670 nm; the light's spectrum at
each setting, ``E_b(lambda)``, is measured with a spectrometer, and the
camera's mean value ``v_bc`` of the target in channel ``c`` is recorded. The
image formation model (per unit exposure) is

    v_bc = sum_l  w_l  E_b(l)  rho(l)  s_c(l)

with trapezoid weights ``w_l`` on the wavelength grid, ``rho`` the target's
reflectance and ``s_c`` the unknown response. With fewer bands than grid
samples the problem is underdetermined; it is solved as Tikhonov-regularized
non-negative least squares (a second-difference smoothness penalty, cf.
P. L. Vora, J. E. Farrell, J. D. Tietz, D. H. Brainard, "Linear models for
digital cameras", IS&T PICS 1997; Lawson-Hanson NNLS via ``scipy.optimize.nnls``):

    min_{s >= 0} || A s - v ||^2 + mu || D2 s ||^2,   mu = lambda ||A||_F^2 / ||D2||_F^2

(``lambda`` dimensionless: the Frobenius norms make it independent of the
units of light and camera values), solved as one NNLS on the stacked system
``[A; sqrt(mu) D2] s = [v; 0]``.

Filter transmittance is the ratio of transmitted to incident spectra
(``T = (transmitted - dark) / (incident - dark)``) where the incident light is
at least ``min_fraction`` of its peak; elsewhere it is undefined (reported
invalid, written as 0).
"""

from __future__ import annotations

import numpy as np

from polarbssrdf.spectral.bands import Band, make_band

__all__ = ["DEFAULT_SMOOTHNESS", "calibrated_bands", "estimate_response", "filter_transmittance",
           "second_difference_matrix", "trapezoid_weights"]

DEFAULT_SMOOTHNESS = 3.0
"""Default regularization weight ``lambda`` of :func:`estimate_response`. Chosen on simulated
captures like the supplement's (bands every 10 nm, 10-15 nm wide, responses on a 5 nm grid,
1% noise): errors are flat within a factor 2 for ``lambda`` in 1-10 (RMS relative error
about 1%, bias 0.5%); much larger values oversmooth (bias 4% at 100), much smaller ones
leave the noise unfiltered (1.6% at <= 0.1). Narrower bands or a finer grid call for
larger values."""


def trapezoid_weights(wavelengths_nm) -> np.ndarray:
    """Weights ``w`` with ``sum(w f) = trapezoid integral of f`` on the grid (nm)."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if wl.ndim != 1 or wl.size < 2 or np.any(np.diff(wl) <= 0):
        raise ValueError("wavelengths must be a strictly increasing 1-D array with >= 2 samples")
    weights = np.zeros_like(wl)
    steps = np.diff(wl)
    weights[:-1] += steps / 2
    weights[1:] += steps / 2
    return weights


def second_difference_matrix(n: int) -> np.ndarray:
    """``(n - 2, n)`` matrix of second differences ``s[i] - 2 s[i + 1] + s[i + 2]``."""
    if n < 3:
        raise ValueError(f"need >= 3 samples for second differences, got {n}")
    D = np.zeros((n - 2, n))
    for i in range(n - 2):
        D[i, i:i + 3] = (1.0, -2.0, 1.0)
    return D


def estimate_response(wavelengths_nm, light_spectra, reflectance, measurements, *,
                      smoothness: float = DEFAULT_SMOOTHNESS) -> np.ndarray:
    """Non-negative, smooth camera responses from narrow-band images of a white reference.

    Parameters
    ----------
    wavelengths_nm:
        ``(L,)`` grid (nm) of the spectra and of the returned responses.
    light_spectra:
        ``(B, L)`` spectral irradiance of each narrow-band setting (any consistent unit).
    reflectance:
        ``(L,)`` reflectance of the reference target (e.g. ~0.99 for Spectralon).
    measurements:
        ``(B, C)`` or ``(B,)`` camera value per band and channel (dark-subtracted,
        divided by exposure).
    smoothness:
        Dimensionless ``lambda`` of the module docstring (>= 0).

    Returns
    -------
    numpy.ndarray
        ``(C, L)`` (or ``(L,)``) responses in camera value per (light unit x nm).
    """
    from scipy.optimize import nnls

    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    weights = trapezoid_weights(wl)
    lights = np.asarray(light_spectra, dtype=np.float64)
    rho = np.asarray(reflectance, dtype=np.float64)
    values = np.asarray(measurements, dtype=np.float64)
    single = values.ndim == 1
    values = values[:, None] if single else values
    if lights.ndim != 2 or lights.shape[1] != wl.size:
        raise ValueError(f"light spectra must be (bands, {wl.size}), got shape {lights.shape}")
    if rho.shape != wl.shape:
        raise ValueError(f"reflectance must have {wl.size} samples, got shape {rho.shape}")
    if values.ndim != 2 or values.shape[0] != lights.shape[0]:
        raise ValueError(f"measurements must be ({lights.shape[0]} bands, channels), got shape "
                         f"{np.shape(measurements)}")
    for name, array in (("light spectra", lights), ("reflectance", rho), ("measurements", values)):
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{name} contain NaN or infinite values")
    if np.any(lights < 0) or np.any(rho < 0):
        raise ValueError("light spectra and reflectance must be >= 0")
    if smoothness < 0:
        raise ValueError(f"smoothness must be >= 0, got {smoothness}")
    A = lights * (rho * weights)[None, :]
    if not np.any(A):
        raise ValueError("light spectra x reflectance are zero everywhere")
    D = second_difference_matrix(wl.size)
    mu = smoothness * np.sum(A ** 2) / np.sum(D ** 2)
    system = np.vstack([A, np.sqrt(mu) * D])
    responses = []
    for column in values.T:
        rhs = np.concatenate([column, np.zeros(D.shape[0])])
        solution, _ = nnls(system, rhs, maxiter=50 * wl.size)
        responses.append(solution)
    responses = np.asarray(responses)
    return responses[0] if single else responses


def filter_transmittance(wavelengths_nm, incident, transmitted, *, dark=None,
                         min_fraction: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Filter transmittance = transmitted / incident spectrum (spectrometer readings).

    Parameters
    ----------
    wavelengths_nm:
        ``(L,)`` grid (nm).
    incident, transmitted:
        ``(L,)`` spectra of the light without and with the filter (same unit and exposure).
    dark:
        Optional ``(L,)`` dark reading subtracted from both.
    min_fraction:
        Where ``incident < min_fraction * max(incident)`` the ratio is undefined.

    Returns
    -------
    (transmittance, valid)
        ``(L,)`` transmittance clipped to ``[0, inf)`` (0 where invalid) and the validity mask.
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    incident = np.asarray(incident, dtype=np.float64)
    transmitted = np.asarray(transmitted, dtype=np.float64)
    if incident.shape != wl.shape or transmitted.shape != wl.shape:
        raise ValueError(f"incident and transmitted spectra must have {wl.size} samples, got "
                         f"{incident.shape} and {transmitted.shape}")
    if dark is not None:
        dark = np.asarray(dark, dtype=np.float64)
        incident, transmitted = incident - dark, transmitted - dark
    if not (np.all(np.isfinite(incident)) and np.all(np.isfinite(transmitted))):
        raise ValueError("spectra contain NaN or infinite values")
    peak = float(incident.max())
    if peak <= 0:
        raise ValueError("incident spectrum has no positive value")
    valid = incident >= min_fraction * peak
    ratio = np.zeros_like(wl)
    ratio[valid] = np.clip(transmitted[valid] / incident[valid], 0.0, None)
    return ratio, valid


def calibrated_bands(wavelengths_nm, responses: dict, filters: dict, light=None) -> list[Band]:
    """Bands ``camera channel x filter x light`` for the renderer and the skin model.

    Parameters
    ----------
    wavelengths_nm:
        Grid (nm) of the bands.
    responses:
        ``{channel: (L,) response}`` on ``wavelengths_nm`` (e.g. from :func:`estimate_response`).
    filters:
        ``{filter name: (L,) transmittance}`` on ``wavelengths_nm``; an empty dict gives one
        band per channel.
    light:
        The stage light's spectrum: a curve accepted by :func:`polarbssrdf.spectral.sample_curve`
        or None for a flat spectrum.

    Returns
    -------
    list of Band
        Named ``<channel><filter>`` (as :func:`polarbssrdf.spectral.default_bands`), sorted by
        centroid; bands with no weight are left out.
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    bands = []
    for channel, response in responses.items():
        for name, transmittance in (filters.items() if filters else [("", None)]):
            curve = None if transmittance is None else (wl, np.asarray(transmittance, dtype=np.float64))
            try:
                band = make_band(f"{channel}{name}", wl, (wl, np.asarray(response, dtype=np.float64)),
                                 curve, light, description=f"calibrated camera {channel}"
                                 + (f" x filter {name}" if name else "") + " x light")
            except ValueError:
                continue  # no overlap between this channel and filter
            bands.append(band)
    return sorted(bands, key=lambda band: band.centroid_nm)
