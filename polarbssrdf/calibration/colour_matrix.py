"""3 x 3 colour-correction matrix from colour-checker patches (colour-science).

The matrix ``M`` maps linear camera RGB to a linear reference space:
``reference ~= camera @ M.T``. It is the least-squares fit of
``colour.characterisation.matrix_colour_correction`` (method "Cheung 2004",
3 terms: T. Cheung, S. Westland, D. Connah, C. Ripamonti, "A comparative study
of the characterisation of colour cameras by means of neural networks and
polynomial transforms", Coloration Technology 2004), as the supplement
(section 3.2) calibrates its colour cameras "by a 3 x 3 matrix". By default
the patches are weighted to minimize relative errors (see
:func:`fit_colour_matrix`).

Reference values come from colour-science's ``CCS_COLOURCHECKERS`` (CIE xyY
under the chart's illuminant, D50 for the X-Rite charts), converted to XYZ or
to linear sRGB (D65, CAT02 adaptation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["COLOUR_SPACES", "DEFAULT_CHECKER", "WEIGHTINGS", "ColourFit", "apply_colour_matrix",
           "checker_reference", "fit_colour_matrix"]

DEFAULT_CHECKER = "ColorChecker24 - After November 2014"
"""colour-science name of the default chart (X-Rite ColorChecker Classic, 2014 formulation)."""

COLOUR_SPACES = ("sRGB", "XYZ")
"""Reference spaces: linear sRGB (D65) or CIE XYZ under the chart's illuminant (Y of white ~0.9)."""


def checker_reference(checker: str = DEFAULT_CHECKER, space: str = "sRGB"
                      ) -> tuple[list[str], np.ndarray]:
    """Patch names and ``(N, 3)`` linear reference values of a colour-science colour checker.

    Parameters
    ----------
    checker:
        A key of ``colour.CCS_COLOURCHECKERS``.
    space:
        ``sRGB`` (linear, D65, CAT02 from the chart's illuminant) or ``XYZ``.
    """
    import colour

    if checker not in colour.CCS_COLOURCHECKERS:
        raise ValueError(f"unknown colour checker {checker!r} "
                         f"(known: {', '.join(sorted(colour.CCS_COLOURCHECKERS.keys()))})")
    if space not in COLOUR_SPACES:
        raise ValueError(f"unknown colour space {space!r} (known: {', '.join(COLOUR_SPACES)})")
    chart = colour.CCS_COLOURCHECKERS[checker]
    names = list(chart.data.keys())
    xyY = np.array(list(chart.data.values()), dtype=np.float64)
    XYZ = colour.xyY_to_XYZ(xyY)
    if space == "XYZ":
        return names, XYZ
    rgb = colour.XYZ_to_RGB(XYZ, "sRGB", illuminant=chart.illuminant,
                            chromatic_adaptation_transform="CAT02", apply_cctf_encoding=False)
    return names, np.asarray(rgb, dtype=np.float64)


@dataclass(frozen=True)
class ColourFit:
    """A fitted colour matrix.

    Attributes
    ----------
    matrix:
        3 x 3, ``reference ~= camera @ matrix.T``.
    residuals:
        ``(N, 3)`` corrected minus reference values.
    rms:
        RMS of ``residuals``.
    """

    matrix: np.ndarray
    residuals: np.ndarray
    rms: float


def _patches(values, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name} must be an N x 3 array of RGB/XYZ values, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return array


WEIGHTINGS = ("relative", "none")
"""Patch weightings of :func:`fit_colour_matrix`."""


def fit_colour_matrix(camera_rgb, reference, *, weighting: str = "relative") -> ColourFit:
    """Least-squares 3 x 3 matrix from linear camera RGB to ``reference`` (colour-science, Cheung 2004).

    Parameters
    ----------
    camera_rgb:
        ``(N, 3)`` linear (dark-subtracted, unclipped) camera values of the patches.
    reference:
        ``(N, 3)`` reference values, e.g. from :func:`checker_reference`.
    weighting:
        ``relative`` (default): each patch's row (camera and reference) is divided by the
        norm of its camera value before the fit, so every patch counts by its *relative*
        error (dark patches as much as the white one; right for noise proportional to the
        signal); ``none``: plain least squares on the values.

    Raises
    ------
    ValueError
        Mismatched shapes, fewer than 3 patches, rank-deficient camera values.
    """
    from colour.characterisation import matrix_colour_correction

    camera = _patches(camera_rgb, "camera values")
    target = _patches(reference, "reference values")
    if camera.shape != target.shape:
        raise ValueError(f"camera values ({camera.shape[0]} patches) and reference values "
                         f"({target.shape[0]} patches) differ in number")
    if camera.shape[0] < 3 or np.linalg.matrix_rank(camera) < 3:
        raise ValueError("camera values must span 3 dimensions (need >= 3 patches of different "
                         "colours, none all zero)")
    if weighting not in WEIGHTINGS:
        raise ValueError(f"unknown weighting {weighting!r} (known: {', '.join(WEIGHTINGS)})")
    scale = np.linalg.norm(camera, axis=1, keepdims=True) if weighting == "relative" else 1.0
    if weighting == "relative" and np.any(scale == 0):
        raise ValueError("a patch has camera value (0, 0, 0); remove it or use weighting='none'")
    matrix = np.asarray(matrix_colour_correction(camera / scale, target / scale,
                                                 method="Cheung 2004", terms=3), dtype=np.float64)
    residuals = camera @ matrix.T - target
    return ColourFit(matrix, residuals, float(np.sqrt(np.mean(residuals ** 2))))


def apply_colour_matrix(rgb, matrix) -> np.ndarray:
    """``rgb @ matrix.T`` over the last axis (images ``H x W x 3`` or ``N x 3``)."""
    rgb = np.asarray(rgb)
    if rgb.shape[-1] != 3:
        raise ValueError(f"last axis must have 3 channels, got shape {rgb.shape}")
    return rgb @ np.asarray(matrix, dtype=rgb.dtype if rgb.dtype.kind == "f" else np.float64).T
