"""Spectral bands: camera response x filter transmittance x light spectrum,
and the band average of any spectral quantity. Wavelengths in nm.

A :class:`Band` stores its sampled weight B(lambda) and serializes to JSON.
``band_average(S, B) = int S(l) B(l) dl / int B(l) dl`` (trapezoid rule on
the band's grid).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from .curves import comb_curve, complementary_curve, gaussian_curve, sample_curve, wavelength_grid

BAND_SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Band:
    """One spectral band: weights B(lambda) >= 0 sampled at wavelengths_nm."""

    name: str
    wavelengths_nm: np.ndarray
    weights: np.ndarray
    description: str = ""
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        wl = np.asarray(self.wavelengths_nm, dtype=float)
        w = np.asarray(self.weights, dtype=float)
        if wl.ndim != 1 or wl.shape != w.shape or wl.size < 2:
            raise ValueError(f"band {self.name!r}: wavelengths and weights must be matching 1-D arrays (>= 2 samples)")
        if np.any(np.diff(wl) <= 0):
            raise ValueError(f"band {self.name!r}: wavelengths must increase strictly")
        if np.any(w < 0) or not np.all(np.isfinite(w)) or np.trapezoid(w, wl) <= 0:
            raise ValueError(f"band {self.name!r}: weights must be finite, >= 0 and not all zero")
        object.__setattr__(self, "wavelengths_nm", wl)
        object.__setattr__(self, "weights", w)

    @property
    def centroid_nm(self) -> float:
        """Weight-averaged wavelength (nm)."""
        return float(np.trapezoid(self.weights * self.wavelengths_nm, self.wavelengths_nm) / np.trapezoid(self.weights, self.wavelengths_nm))

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "description": self.description,
            "wavelengths_nm": self.wavelengths_nm.tolist(),
            "weights": self.weights.tolist(),
            "metadata": dict(self.metadata),
        }

    @classmethod
    def from_dict(cls, data: dict) -> "Band":
        try:
            return cls(
                name=str(data["name"]),
                wavelengths_nm=np.asarray(data["wavelengths_nm"], dtype=float),
                weights=np.asarray(data["weights"], dtype=float),
                description=str(data.get("description", "")),
                metadata=dict(data.get("metadata", {})),
            )
        except KeyError as missing:
            raise ValueError(f"band description lacks field {missing}") from None


def make_band(name, wavelengths_nm, camera=None, filter=None, light=None, description="") -> Band:  # noqa: A002
    """Band weight = camera response x filter transmittance x light spectrum
    (each a curve, see :mod:`polarbssrdf.spectral.curves`; None = 1)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    weight = np.ones_like(wl)
    for curve in (camera, filter, light):
        if curve is not None:
            weight = weight * sample_curve(curve, wl)
    return Band(name, wl, weight, description)


def default_camera_responses() -> dict:
    """Analytic RGB responses of a colour polarization camera (Gaussian-ish,
    peaks 460 / 530 / 600 nm, 60 nm FWHM) as curves."""
    return {
        "B": gaussian_curve(460.0, 60.0),
        "G": gaussian_curve(530.0, 60.0, 0.95),
        "R": gaussian_curve(600.0, 60.0, 0.9),
    }


DEFAULT_COMB_PERIOD_NM = 70.0
DEFAULT_COMB_PHASE_NM = 440.0


def comb_filter_pair(period_nm: float = DEFAULT_COMB_PERIOD_NM, phase_nm: float = DEFAULT_COMB_PHASE_NM) -> dict:
    """Two complementary comb filters: 'A' passes around ``phase + m period`` (nm), 'B'
    between its teeth (:func:`~.curves.comb_curve`, :func:`~.curves.complementary_curve`)."""
    if not (np.isfinite(period_nm) and period_nm > 0 and np.isfinite(phase_nm)):
        raise ValueError(f"a comb filter needs a finite period > 0 nm and a finite phase, got "
                         f"period {period_nm!r}, phase {phase_nm!r}")
    comb_a = comb_curve(float(period_nm), float(phase_nm))
    return {"A": comb_a, "B": complementary_curve(comb_a)}


def default_filters() -> dict:
    """Two complementary comb filters (70 nm period): 'A' passes around
    440, 510, 580, 650 nm and 'B' around 405, 475, 545, 615, 685 nm, so each
    camera channel splits into two bands."""
    return comb_filter_pair()


def default_light():
    """A white phosphor LED: CIE LED-B3 (colour-science's SDS_ILLUMINANTS)."""
    from colour import SDS_ILLUMINANTS  # imported here: see polarbssrdf.spectral.curves

    return SDS_ILLUMINANTS["LED-B3"]


def default_bands(wavelengths_nm=None) -> list[Band]:
    """The default 6 bands: {B, G, R} camera channels x {A, B} comb filters
    x white LED, sampled at 400-700 nm every 5 nm, sorted by centroid."""
    return comb_pair_bands(DEFAULT_COMB_PERIOD_NM, DEFAULT_COMB_PHASE_NM, wavelengths_nm)


def comb_pair_bands(period_nm, phase_nm, wavelengths_nm=None) -> list[Band]:
    """The 6 bands of a colour camera behind a pair of complementary comb filters:
    {B, G, R} channels (:func:`default_camera_responses`) x {A, B}
    (:func:`comb_filter_pair`) x white LED, sampled at ``wavelengths_nm`` (400-700 nm
    every 5 nm by default), sorted by centroid. Period 70 nm, phase 440 nm are the
    default bands."""
    wl = wavelength_grid(400.0, 700.0, 5.0) if wavelengths_nm is None else np.asarray(wavelengths_nm, dtype=float)
    filters = comb_filter_pair(period_nm, phase_nm)
    bands = []
    for channel, camera in default_camera_responses().items():
        for filt_name, filt in filters.items():
            band = make_band(f"{channel}{filt_name}", wl, camera, filt, default_light(),
                             description=f"camera {channel} x comb filter {filt_name} x LED-B3")
            bands.append(band)
    return sorted(bands, key=lambda b: b.centroid_nm)


def bandpass_bands(centres_nm, fwhm_nm, wavelengths_nm=None, light="default") -> list[Band]:
    """Bands of Gaussian bandpass filters (centre, full width at half maximum in nm) on a
    spectrally flat (monochrome) camera under the white LED (``light=None``: none),
    sampled at ``wavelengths_nm`` (400-700 nm every 1 nm by default); named ``bp<centre>``.

    ``fwhm_nm`` is one width or one per centre. A filter with no weight on the grid is
    refused, naming it."""
    centres = np.atleast_1d(np.asarray(centres_nm, dtype=float))
    widths = np.broadcast_to(np.asarray(fwhm_nm, dtype=float), centres.shape)
    if centres.ndim != 1 or centres.size == 0:
        raise ValueError("bandpass filters need at least one centre wavelength")
    if not (np.all(np.isfinite(centres)) and np.all(np.isfinite(widths)) and np.all(widths > 0)):
        raise ValueError(f"bandpass centres must be finite and widths > 0 nm, got centres "
                         f"{centres.tolist()}, widths {widths.tolist()}")
    wl = wavelength_grid(400.0, 700.0, 1.0) if wavelengths_nm is None else np.asarray(wavelengths_nm, dtype=float)
    light = default_light() if light == "default" else light
    bands = []
    for centre, width in zip(centres, widths):
        if not wl[0] <= centre <= wl[-1]:
            raise ValueError(f"bandpass centre {centre:g} nm is outside the wavelength grid "
                             f"{wl[0]:g}-{wl[-1]:g} nm")
        name = f"bp{centre:g}"
        bands.append(make_band(name, wl, filter=gaussian_curve(float(centre), float(width)), light=light,
                               description=f"{width:g} nm FWHM bandpass at {centre:g} nm"
                                           + (" x LED-B3" if light is not None else "")))
    names = [band.name for band in bands]
    if len(set(names)) != len(names):
        raise ValueError(f"bandpass centres must be distinct, got {centres.tolist()}")
    return bands


def bands_to_json(bands) -> str:
    """JSON text for a list of bands (with a schema version)."""
    return json.dumps({"schema_version": BAND_SCHEMA_VERSION, "bands": [b.to_dict() for b in bands]})


def bands_from_json(text: str) -> list[Band]:
    """Inverse of :func:`bands_to_json`."""
    data = json.loads(text)
    if not isinstance(data, dict):
        raise ValueError(f"expected a JSON object {{\"schema_version\": {BAND_SCHEMA_VERSION}, "
                         f"\"bands\": [...]}}, got a JSON {type(data).__name__}")
    if data.get("schema_version") != BAND_SCHEMA_VERSION:
        raise ValueError(f"unsupported band schema version {data.get('schema_version')!r}")
    entries = data.get("bands")
    if not isinstance(entries, list) or not all(isinstance(b, dict) for b in entries):
        raise ValueError("'bands' must be a list of objects with 'name', 'wavelengths_nm' and "
                         "'weights'")
    return [Band.from_dict(b) for b in entries]


def band_weights_matrix(bands, wavelengths_nm) -> np.ndarray:
    """Matrix M (n_bands x n_wavelengths) with values @ M.T = band averages
    for spectra sampled at ``wavelengths_nm`` (trapezoid rule, band weights
    interpolated onto that grid, zero outside the band's range)."""
    wl = np.asarray(wavelengths_nm, dtype=float)
    if wl.ndim != 1 or wl.size < 2 or np.any(np.diff(wl) <= 0):
        raise ValueError("wavelengths must be a strictly increasing 1-D array (>= 2 samples)")
    dl = np.gradient(wl) if wl.size > 2 else np.full(wl.shape, wl[1] - wl[0])
    trap = np.concatenate([[0.5 * (wl[1] - wl[0])], 0.5 * (wl[2:] - wl[:-2]), [0.5 * (wl[-1] - wl[-2])]]) if wl.size > 2 else dl / 2
    rows = []
    for band in bands:
        w = np.interp(wl, band.wavelengths_nm, band.weights, left=0.0, right=0.0) * trap
        total = w.sum()
        if total <= 0:
            raise ValueError(f"band {band.name!r} has no weight on the grid {wl[0]:g}-{wl[-1]:g} nm")
        rows.append(w / total)
    return np.asarray(rows)


def band_average(spectrum, band: Band) -> np.ndarray:
    """int S(l) B(l) dl / int B(l) dl on the band's own wavelength grid.

    ``spectrum`` is a curve (SpectralDistribution, (wl, values) pair or
    callable) or an array whose last axis is sampled at
    ``band.wavelengths_nm`` (leading axes are kept, e.g. texels)."""
    wl, w = band.wavelengths_nm, band.weights
    if isinstance(spectrum, np.ndarray) or (isinstance(spectrum, list)):
        values = np.asarray(spectrum, dtype=float)
        if values.shape[-1] != wl.size:
            raise ValueError(f"spectrum has {values.shape[-1]} samples, band {band.name!r} has {wl.size}")
    else:
        values = sample_curve(spectrum, wl)
    return np.trapezoid(values * w, wl, axis=-1) / np.trapezoid(w, wl)


DEFAULT_BANDS_FILE = "default_bands.json"
"""The default bands as shipped sampled curves (``polarbssrdf/spectral/data``)."""


def read_bands(path) -> list[Band]:
    """Bands from a JSON file written by :func:`bands_to_json`; errors name the file."""
    from pathlib import Path

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"band file not found: {path}")
    try:
        bands = bands_from_json(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from error
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: not a band file ({error})") from error
    names = [band.name for band in bands]
    if not bands or len(set(names)) != len(names):
        raise ValueError(f"{path}: needs at least one band and unique band names, got {names}")
    return bands


def shipped_default_bands() -> list[Band]:
    """The 6 default bands read from the JSON file shipped with the package."""
    from importlib import resources

    with resources.as_file(resources.files("polarbssrdf.spectral") / "data" / DEFAULT_BANDS_FILE) as path:
        return read_bands(path)
