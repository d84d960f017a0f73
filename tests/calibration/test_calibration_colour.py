"""3 x 3 colour matrix from colour-checker patches."""

import colour
import numpy as np
import pytest

from polarbssrdf.calibration import apply_colour_matrix, checker_reference, fit_colour_matrix

TRUE_MATRIX = np.array([[1.62, -0.41, -0.21],
                        [-0.27, 1.48, -0.21],
                        [0.04, -0.55, 1.51]])
"""Camera RGB -> linear sRGB, rows summing to 1 (white stays white), typical of real cameras."""


def test_reference_data_come_from_colour_science():
    names, rgb = checker_reference()
    assert len(names) == 24 and names[0] == "dark skin" and names[18].startswith("white")
    # neutral patches are neutral after adaptation to D65, and darken down the row
    neutrals = rgb[18:24]
    assert np.all(np.abs(neutrals / neutrals.mean(axis=1, keepdims=True) - 1) < 0.07)
    assert np.all(np.diff(neutrals.mean(axis=1)) < 0)
    # Y of the white patch ~ 0.9 (a matte white chart), of the black one ~ 0.03
    _, XYZ = checker_reference(space="XYZ")
    assert 0.85 < XYZ[18, 1] < 0.92 and 0.02 < XYZ[23, 1] < 0.04


@pytest.mark.parametrize("weighting", ["relative", "none"])
def test_known_matrix_is_recovered_from_noisy_patches(weighting):
    _, reference = checker_reference()
    rng = np.random.default_rng(5)
    errors = []
    for _ in range(5):
        camera = reference @ np.linalg.inv(TRUE_MATRIX).T
        camera = camera * (1.0 + 0.01 * rng.standard_normal(camera.shape))  # 1% noise
        fit = fit_colour_matrix(camera, reference, weighting=weighting)
        errors.append(np.linalg.norm(fit.matrix - TRUE_MATRIX) / np.linalg.norm(TRUE_MATRIX))
        assert np.abs(fit.matrix - TRUE_MATRIX).max() < 0.02 * np.abs(TRUE_MATRIX).max()
    assert max(errors) < 0.02
    # the residual is at the noise level (1% of the corrected values)
    assert fit.rms < 0.02 * np.sqrt(np.mean(reference ** 2))


@pytest.mark.filterwarnings("ignore::colour.utilities.ColourRuntimeWarning")
def test_matrix_of_a_spectrally_simulated_camera_corrects_the_chart():
    """Camera RGB integrated from colour-science's chart reflectances, D65 and a real camera's
    sensitivities: the 3 x 3 matrix brings the white patch to the reference white."""
    shape = colour.SpectralShape(400, 700, 10)
    sensitivities = colour.characterisation.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"].copy().align(shape)
    illuminant = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    chart = colour.characterisation.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    camera = np.array([[np.sum(sd.copy().align(shape).values * illuminant.values
                               * sensitivities.values[:, c]) for c in range(3)]
                       for sd in chart.values()])
    camera /= camera[18, 1]
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    XYZ = np.array([colour.sd_to_XYZ(sd.copy().align(shape), cmfs=cmfs, illuminant=illuminant) / 100
                    for sd in chart.values()])
    reference = colour.XYZ_to_RGB(XYZ, "sRGB", apply_cctf_encoding=False)
    fit = fit_colour_matrix(camera, reference)
    corrected = apply_colour_matrix(camera, fit.matrix)
    assert np.abs(corrected[18] - reference[18]).max() < 0.03 * reference[18].max()
    assert fit.rms < 0.03


def test_bad_patch_values_are_clear_errors():
    _, reference = checker_reference()
    with pytest.raises(ValueError, match="differ in number"):
        fit_colour_matrix(reference[:20], reference)
    with pytest.raises(ValueError, match="N x 3"):
        fit_colour_matrix(reference[:, :2], reference[:, :2])
    with pytest.raises(ValueError, match="span 3 dimensions"):
        fit_colour_matrix(np.ones((24, 3)), reference)
    with pytest.raises(ValueError, match="unknown weighting 'huber'"):
        fit_colour_matrix(reference, reference, weighting="huber")
    with pytest.raises(ValueError, match="unknown colour checker 'Macbeth'"):
        checker_reference("Macbeth")
