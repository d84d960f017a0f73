"""What the bands can tell: Cramér-Rao bounds of the chromophores, checked against an
independent per-texel fit, and the band-design search."""

import itertools
import json

import mitsuba as mi
import numpy as np
import pytest
from scipy.optimize import least_squares

from polarbssrdf.cli import main
from polarbssrdf.render.subsurface import subsurface_exit_fraction
from polarbssrdf.skin import band_information as info
from polarbssrdf.skin.inversion import _Model
from polarbssrdf.skin.parameters import TABLE2, SkinParameters
from polarbssrdf.skin.quadrature import quadrature_reflectance, spectral_quadrature
from polarbssrdf.spectral import bandpass_bands, bands_to_json, comb_pair_bands, shipped_default_bands

ROW = ("forehead", "IV")


@pytest.fixture(scope="module")
def bands():
    return shipped_default_bands()


def test_the_jacobian_is_the_inversions_analytic_one(bands):
    """Central differences of the band-integrated band_reflectance vs the chain rule through
    the inversion's Hermite tables at the quadrature's nodes, projected on the bands (another
    code path: exact derivatives of an interpolant whose slopes are good to about 2e-5), and
    a step in the plateau (half of it changes J by < 1e-5)."""
    quadrature = spectral_quadrature(bands)
    for row in [("forehead", "I"), ROW, ("cheek", "III")]:
        skin = TABLE2[row]
        theta = np.array([[skin.C_m, skin.beta_m, skin.C_h_out, skin.C_h_in]])
        albedo, jacobian = info.albedo_jacobian(*theta[0], bands, skin.eta)
        value, reference = _Model(quadrature.basis, 0.75, 0.25, skin.eta,
                                  projection=quadrature.weights).value_and_jacobian(theta)
        np.testing.assert_allclose(albedo, value[0], rtol=1e-8)
        np.testing.assert_allclose(jacobian, reference[0], rtol=5e-5, atol=1e-6 * np.abs(reference).max())
        _, finer = info.albedo_jacobian(*theta[0], bands, skin.eta, step=info.JACOBIAN_STEP / 2)
        assert np.abs(finer - jacobian).max() < 1e-5 * np.abs(jacobian).max()


def test_relative_noise_ignores_the_exit_fraction_and_absolute_noise_scales_with_it(bands):
    rows = [ROW, ("cheek", "I")]
    relative = [info.band_bounds(bands, info.white_noise(0.01), rows, exit_fraction=f).std
                for f in (None, subsurface_exit_fraction)]
    # equal but for the central differences' rounding (1e-12 of J), which the Fisher matrix's
    # condition number (1e3-1e4 here) carries into the bound
    np.testing.assert_allclose(relative[0], relative[1], rtol=1e-7)
    flux, lobe = (info.band_bounds(bands, info.white_noise(0.005, relative=False), rows, exit_fraction=f).std
                  for f in (None, subsurface_exit_fraction))
    c = subsurface_exit_fraction([TABLE2[r].eta for r in rows])
    # rho = R / c: the same absolute error on rho is c times larger on R, and so is the bound
    np.testing.assert_allclose(lobe, flux * c[:, None], rtol=1e-7)


def test_a_diagonal_covariance_is_white_noise_and_a_common_error_costs(bands):
    white = info.band_bounds(bands, info.white_noise(0.01))
    diagonal = info.band_bounds(bands, info.NoiseModel("covariance", matrix=1e-4 * np.eye(6)))
    np.testing.assert_allclose(diagonal.std, white.std, rtol=1e-9)
    n = len(bands)
    common = info.NoiseModel("covariance", matrix=1e-4 * np.eye(n) + 0.02 ** 2 * np.ones((n, n)))
    costly = info.band_bounds(bands, common).std
    # a common error never lowers a bound; it raises those of the chromophores whose band
    # signature has a common part (C_m, C_h_out: by 1-15% here). For C_h_in of some rows the
    # signature, the other parameters marginalized, is orthogonal to the common direction:
    # its bound moves by 1e-12 of itself (either sign, rounding) on a 2-core AMD EPYC
    assert np.all(costly >= white.std * (1 - 1e-9))
    chromophores = [info.PARAMETERS.index("C_m"), info.PARAMETERS.index("C_h_out")]
    assert np.all(costly[:, chromophores] > white.std[:, chromophores])


def test_no_band_lowers_the_bound_by_being_removed(bands):
    bounds = info.band_bounds(bands, info.white_noise(0.01))
    pins = info.band_pins(bounds)
    assert pins.shape == (len(bands), 8, 4)
    assert np.all(pins >= 1.0 - 1e-9)  # removing information never tightens the bound
    # with four bands, removing any one leaves three for four unknowns
    four = info.band_bounds(bands[:4], info.white_noise(0.01), [ROW])
    assert np.all(np.isinf(info.band_pins(four)))


def test_too_few_bands_are_reported_not_an_error(bands):
    bounds = info.band_bounds(bands[:3], info.white_noise(0.01))
    assert not bounds.identifiable.any() and np.all(np.isinf(bounds.condition))
    data = info.report_json(bounds)
    assert data["rows"][0]["std"]["C_m"] is None and data["rows"][0]["identifiable"]["beta_m"] is False
    json.dumps(data, allow_nan=False)  # infinite bounds are null, so the JSON is strict
    assert "inf" in info.format_report(bounds)
    # a prior makes the Bayesian bound finite, and never above the prior's spread
    prior = info.band_bounds(bands[:3], info.white_noise(0.01), prior="rows")
    spread = info.prior_spreads("rows", prior.rows)
    assert prior.identifiable.all() and np.all(prior.std <= spread * (1 + 1e-9))


def test_an_unseen_direction_makes_only_its_chromophores_infinite():
    block = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.5], [0.0, 0.5, 2.0]])
    information = np.zeros((4, 4))
    information[:3, :3] = block
    covariance, std, condition = info.bound_from_information(information, np.ones(4))
    np.testing.assert_allclose(covariance[:3, :3], np.linalg.inv(block), rtol=1e-12)
    assert np.isinf(std[3]) and np.isfinite(std[:3]).all() and np.isinf(condition)


def fit_draws(observed, bands, skin, whiten):
    """Per-draw maximum-likelihood fit without prior: scipy least_squares on the band-integrated
    skin model (at the thickness and oxygenation the bound assumes)."""
    quadrature = spectral_quadrature(bands)
    start = np.array([skin.C_m, skin.beta_m, skin.C_h_out, skin.C_h_in])
    out = []
    for value in observed:
        def residual(p):
            model = quadrature_reflectance(quadrature, *p, 0.75, 0.25, skin.eta)
            return whiten @ ((model - value) / value)
        # within the model's domain (a step to beta_m < 0 on a texel near 0 is refused by it)
        fit = least_squares(residual, start, method="trf", bounds=(0.0, 1.0), x_scale=np.full(4, 0.01),
                            diff_step=1e-6, xtol=1e-10, ftol=1e-10)
        out.append(fit.x)
    return np.array(out)


@pytest.mark.parametrize("kind", ["white", "correlated"])
def test_the_bound_is_the_spread_of_a_per_texel_fit(bands, kind):
    """Noisy draws of one Table 2 row's albedo, each fitted per texel (no prior, no smoothness):
    the spread of every chromophore is the Cramér-Rao bound within 30% (120 draws: the
    sampling error of a standard deviation is 6.5%). The noise is small enough (0.1%) for the
    fit to be in its linear regime; at the fit's 1% the bound of beta_m exceeds its range."""
    skin = TABLE2[ROW]
    n = len(bands)
    if kind == "white":
        matrix = 0.001 ** 2 * np.eye(n)
    else:  # a common gain error beside per-band noise, as the static albedo's (issue 20)
        matrix = 0.0005 ** 2 * np.eye(n) + 0.0009 ** 2 * np.ones((n, n))
    noise = info.NoiseModel("covariance", matrix=matrix)
    bounds = info.band_bounds(bands, noise, [ROW])
    rng = np.random.default_rng(7)
    clean = bounds.albedo[0]
    observed = clean * (1.0 + rng.multivariate_normal(np.zeros(n), matrix, size=120))
    whiten = np.linalg.inv(np.linalg.cholesky(matrix))
    estimates = fit_draws(observed, bands, skin, whiten)
    truth = np.array([skin.C_m, skin.beta_m, skin.C_h_out, skin.C_h_in])
    spread = estimates.std(axis=0)
    np.testing.assert_allclose(spread / bounds.std[0], 1.0, atol=0.3)
    assert np.all(np.abs(estimates.mean(axis=0) - truth) < 0.35 * bounds.std[0])  # unbiased (3.8 sigma)


def test_the_bound_predicts_the_error_on_synthetic_maps(bands):
    """Synth's truth maps (bases off Table 2, spatial variation), its albedo, 0.05% relative noise,
    a per-texel fit: errors over the per-texel bound have unit spread within 30%."""
    from polarbssrdf.geometry import texel_atlas, to_mitsuba
    from polarbssrdf.synth.synthesize import object_mesh, subsurface_albedo
    from polarbssrdf.synth.truth import table2_offset_settings, truth_maps

    mi.set_variant("llvm_ad_mono_polarized")
    atlas = texel_atlas(to_mitsuba(object_mesh("sphere")), 32)
    known = {"thickness_mm": (0.25, 0.0, 0.10, 0.40), "gamma": (0.75, 0.0, 0.50, 0.95)}  # the bound's
    maps = truth_maps(atlas, table2_offset_settings(("cheek", "II"), 1.5, skin_layers=known),
                      np.random.default_rng(3))
    albedo = np.moveaxis(subsurface_albedo(maps, bands), 0, -1)[atlas.valid].astype(np.float64)
    texels = np.random.default_rng(4).choice(albedo.shape[0], 120, replace=False)
    truth = np.stack([maps[n][atlas.valid][texels] for n in info.PARAMETERS], -1).astype(np.float64)
    eta = maps["eta"][atlas.valid][texels].astype(np.float64)
    sigma = 0.0005
    _, jacobian = info.albedo_jacobian(*truth.T, bands, eta, exit_fraction=subsurface_exit_fraction)
    noise = info.white_noise(sigma)
    information = info.fisher_information(jacobian, noise.covariance(albedo[texels]))
    _, std, _ = info.bound_from_information(information, info.table2_scale())
    observed = albedo[texels] * (1.0 + sigma * np.random.default_rng(5).standard_normal(albedo[texels].shape))
    z = []
    for value, skin_theta, e, bound in zip(observed, truth, eta, std):
        skin = SkinParameters(*skin_theta, eta=float(e))
        # the fit sees R_bar = c(eta) rho (the stage's definition); relative noise is the same on both
        estimate = fit_draws((value * subsurface_exit_fraction(e))[None], bands, skin, np.eye(len(bands)) / sigma)
        z.append((estimate[0] - skin_theta) / bound)
    np.testing.assert_allclose(np.std(z, axis=0), 1.0, atol=0.3)


def test_design_finds_the_exhaustive_optimum_and_greedy_is_no_better():
    candidates = bandpass_bands(np.arange(420, 700, 40), 10)  # 7 candidates
    noise = info.white_noise(0.01)
    exhaustive = info.design_bands(candidates, 5, noise, search="exhaustive")
    greedy = info.design_bands(candidates, 5, noise, search="greedy")
    assert greedy.value >= exhaustive.value * (1 - 1e-12)
    # the exhaustive optimum is the best of every subset, each scored independently
    scores = {subset: info.band_bounds([candidates[i] for i in subset], noise).criterion("mean")
              for subset in itertools.combinations(range(7), 5)}
    best = min(scores, key=scores.get)
    assert sorted(exhaustive.chosen) == list(best)
    assert exhaustive.value == pytest.approx(scores[best], rel=1e-9)
    assert greedy.value == pytest.approx(scores[tuple(sorted(greedy.chosen))], rel=1e-9)
    worst = info.design_bands(candidates, 4, noise, criterion="worst", search="exhaustive")
    assert worst.value == pytest.approx(info.band_bounds(worst.bands, noise).criterion("worst"), rel=1e-9)


def test_design_refuses_what_it_cannot_do():
    candidates = bandpass_bands([450, 500, 550, 600, 650], 10)
    with pytest.raises(ValueError, match="parametric noise model"):
        info.design_bands(candidates, 4, info.NoiseModel("covariance", matrix=np.eye(5)))
    with pytest.raises(ValueError, match="k must be"):
        info.design_bands(candidates, 6, info.white_noise(0.01))
    with pytest.raises(ValueError, match="criterion must be"):
        info.design_bands(candidates, 4, info.white_noise(0.01), criterion="median")


def test_the_comb_pair_search_scores_the_default_pair_as_the_default_bands(bands):
    noise = info.white_noise(0.01)
    period, phase, value, grid = info.design_comb_pair([60.0, 70.0], [430.0, 440.0], noise)
    scores = {(p, q): v for p, q, v in grid}
    assert scores[(70.0, 440.0)] == pytest.approx(info.band_bounds(bands, noise).criterion("mean"), rel=1e-6)
    assert value == min(scores.values()) and scores[(period, phase)] == value


def test_bands_command_table_and_json(tmp_path, capsys, bands):
    out = tmp_path / "report.json"
    held = ["--noise-common", "0", "--nuisances", "none"]
    assert main(["skin", "bands", "--noise", "0.02", *held, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "forehead IV" in text and "pins" in text and "C_h_in" in text
    data = json.loads(out.read_text())
    assert data["schema"] == "polarbssrdf.band_report" and len(data["rows"]) == 8
    expected = info.band_bounds(bands, info.white_noise(0.02), exit_fraction=subsurface_exit_fraction)
    assert data["rows"][3]["std"]["C_m"] == pytest.approx(expected.std[3, 0], rel=1e-9)
    assert [p["band"] for p in data["pins"]] == [b.name for b in bands]
    # the same through a band file, a covariance file with named bands, and the comb pair
    band_file = tmp_path / "bands.json"
    band_file.write_text(bands_to_json(bands))
    names = [b.name for b in bands][::-1]
    covariance = tmp_path / "cov.json"
    covariance.write_text(json.dumps({"bands": names, "covariance": (4e-4 * np.eye(6)).tolist()}))
    assert main(["skin", "bands", "--bands", str(band_file), "--covariance", str(covariance),
                 "--nuisances", "none", "--out", str(tmp_path / "cov_report.json")]) == 0
    again = json.loads((tmp_path / "cov_report.json").read_text())
    assert again["rows"][3]["std"]["C_m"] == pytest.approx(expected.std[3, 0], rel=1e-9)
    assert main(["skin", "bands", "--comb", "70", "440", *held, "--out", str(tmp_path / "comb.json")]) == 0
    comb = json.loads((tmp_path / "comb.json").read_text())
    assert comb["rows"][0]["std"]["C_m"] == pytest.approx(data["rows"][0]["std"]["C_m"] / 2, rel=1e-3)
    assert main(["skin", "bands", "--centres", "420,470,590,680", "--widths", "10"]) == 0
    # the defaults: the fit's noise (1% per band, 1% common) and its nuisances marginalized
    capsys.readouterr()
    assert main(["skin", "bands", "--out", str(tmp_path / "defaults.json")]) == 0
    assert "marginalized (prior std) thickness_mm" in capsys.readouterr().out
    defaults = json.loads((tmp_path / "defaults.json").read_text())
    fit_like = info.band_bounds(bands, info.white_noise(0.01, common=0.01), exit_fraction=subsurface_exit_fraction,
                                nuisances="default")
    assert defaults["rows"][3]["std"]["C_h_in"] == pytest.approx(fit_like.std[3, 3], rel=1e-9)
    assert defaults["nuisances"]["held"] == [] and defaults["noise"]["common"] == 0.01
    custom = tmp_path / "custom.json"
    assert main(["skin", "bands", "--nuisances", "thickness_mm=0.03", "--out", str(custom)]) == 0
    assert json.loads(custom.read_text())["nuisances"]["held"] == ["gamma", "eta"]


def test_design_command_writes_a_band_file_the_report_reads(tmp_path, capsys):
    best = tmp_path / "best.json"
    assert main(["skin", "design-bands", "-k", "4", "--candidates", "420:680:40", "--write-bands", str(best),
                 "--out", str(tmp_path / "design.json")]) == 0
    design = json.loads((tmp_path / "design.json").read_text())
    assert len(design["design"]["chosen"]) == 4
    assert design["chosen"]["criteria"]["mean"] < design["default_bands"]["criteria"]["mean"]
    capsys.readouterr()
    assert main(["skin", "bands", "--bands", str(best), "--out", str(tmp_path / "r.json")]) == 0
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["criteria"]["mean"] == pytest.approx(design["chosen"]["criteria"]["mean"], rel=1e-9)


@pytest.mark.parametrize("argv, message", [
    (["skin", "bands", "--noise", "0"], "noise level must be a number > 0"),
    (["skin", "bands", "--noise-absolute", "-0.01"], "noise level must be a number > 0"),
    (["skin", "bands", "--bands", "missing.json"], "band file not found"),
    (["skin", "bands", "--centres", "380,450,550,650"], "outside the wavelength grid 400-700 nm"),
    (["skin", "bands", "--centres", "450,550,650", "--widths", "10,20"], "one width or one per centre"),
    (["skin", "bands", "--thickness", "0"], "--thickness must be > 0"),
    (["skin", "design-bands", "--candidates", "400:700:0"], "bad wavelengths"),
    (["skin", "design-bands", "-k", "40"], "k must be an integer"),
    (["skin", "bands", "--nuisances", "thickness=0.05"], "--nuisances: unknown nuisance(s) ['thickness']"),
    (["skin", "bands", "--nuisances", "gamma"], "--nuisances: expected 'default', 'none' or name=std"),
    (["skin", "bands", "--noise-absolute", "0.01", "--noise-common", "0.01"], "--noise-common goes with"),
])
def test_bad_input_is_one_line_naming_it(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


@pytest.mark.parametrize("content, message", [
    ({"covariance": [[1e-4, 0], [1e-5, 1e-4]]}, "not symmetric"),
    ({"covariance": [[1e-4, 2e-4], [2e-4, 1e-4]]}, "not positive definite"),
    ({"covariance": (1e-4 * np.eye(5)).tolist()}, "a 5 x 5 matrix for 6 bands"),
    ({"bands": ["BA", "BB", "GA", "GB", "RA", "XX"], "covariance": (1e-4 * np.eye(6)).tolist()},
     "the band set has"),
    ({"matrix": [[1]]}, "key 'covariance'"),
])
def test_bad_covariance_files_are_named(tmp_path, capsys, content, message):
    path = tmp_path / "cov.json"
    path.write_text(json.dumps(content))
    assert main(["skin", "bands", "--covariance", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and "cov.json" in err


def test_an_existing_out_file_is_refused_naming_the_flag_that_replaces_it(tmp_path):
    """Issue 32, item 14: 'skin bands --out EXISTING' said "pass overwrite=True", which no
    command-line option does."""
    from helpers import run_cli

    out = tmp_path / "report.json"
    out.write_text("{}")
    status, _, stderr = run_cli("skin", "bands", "--out", out)
    assert status == 2 and stderr.count("\n") == 1
    assert "pass --overwrite to replace it" in stderr and "overwrite=True" not in stderr
    assert out.read_text() == "{}"
    status, _, stderr = run_cli("skin", "bands", "--out", out, "--overwrite")
    assert status == 0, stderr
    assert json.loads(out.read_text())["schema"] == "polarbssrdf.band_report"
    # from Python the same refusal names the parameter
    from polarbssrdf.io.atomic import atomic_write_text

    with pytest.raises(FileExistsError, match=r"pass overwrite=True to replace it"):
        atomic_write_text(out, "x")


def test_marginalizing_is_the_chromophore_block_of_the_joint_posterior(bands):
    """The Schur complement against the joint information inverted whole (prior on the
    nuisances only), a vanishing nuisance prior gives the held bound, and a nuisance can only
    widen the bound."""
    noise = info.white_noise(0.01)
    priors = {"thickness_mm": 0.05, "gamma": 0.08, "eta": 0.015}
    held = info.band_bounds(bands, noise)
    marginal = info.band_bounds(bands, noise, nuisances=priors)
    assert marginal.jacobian.shape[-1] == 7
    joint = info.fisher_information(marginal.jacobian, noise.covariance(marginal.albedo))
    joint[:, 4:, 4:] += np.diag([1 / s ** 2 for s in priors.values()])
    expected = np.linalg.inv(joint)[:, :4, :4]
    np.testing.assert_allclose(marginal.covariance, expected, rtol=1e-6)
    tiny = info.band_bounds(bands, noise, nuisances={k: 1e-9 for k in priors})
    np.testing.assert_allclose(tiny.std, held.std, rtol=1e-6)
    assert np.all(marginal.std >= held.std * (1 - 1e-9))
    assert info.band_bounds(bands, noise, nuisances={"thickness_mm": 0}).std == pytest.approx(held.std)
    with pytest.raises(ValueError, match="unknown nuisance"):
        info.band_bounds(bands, noise, nuisances={"melanin": 0.1})
    with pytest.raises(ValueError, match="thickness_mm: the prior std"):
        info.band_bounds(bands, noise, nuisances={"thickness_mm": -0.1})


def test_the_nuisance_columns_are_the_derivatives_in_the_named_unknowns(bands):
    """Each nuisance column against a wide central difference of the lobe albedo taken by
    moving that argument of band_reflectance alone (catches a column wired to another unknown)."""
    from polarbssrdf.skin.model import band_reflectance

    skin = TABLE2[ROW]
    theta = (skin.C_m, skin.beta_m, skin.C_h_out, skin.C_h_in)
    at = {"thickness_mm": 0.27, "gamma": 0.72, "eta": 1.41}
    _, jacobian = info.albedo_jacobian(*theta, bands, at["eta"], at["thickness_mm"], at["gamma"],
                                       subsurface_exit_fraction, nuisances=("gamma", "eta", "thickness_mm"))

    def albedo(**moved):
        p = {**at, **moved}
        return band_reflectance(*theta, bands, gamma=p["gamma"], thickness_mm=p["thickness_mm"],
                                eta=p["eta"]) / subsurface_exit_fraction(p["eta"])

    for column, name in zip((4, 5, 6), ("gamma", "eta", "thickness_mm")):
        h = 1e-4
        expected = (albedo(**{name: at[name] + h}) - albedo(**{name: at[name] - h})) / (2 * h)
        np.testing.assert_allclose(jacobian[:, column], expected, rtol=2e-3, atol=1e-6 * np.abs(expected).max())


def test_the_marginal_bound_is_the_spread_of_a_fit_with_the_nuisances_unknown(bands):
    """Draws with the nuisances drawn from their prior and 0.1% noise, each fitted per texel
    for the four chromophores and the three nuisances with that Gaussian prior (scipy, MAP):
    the chromophores' spread is the marginal bound within 30% (120 draws); the held bound
    (nuisances known) is narrower for C_h_in, so the check can tell the two apart."""
    skin = TABLE2[ROW]
    n = len(bands)
    sigma = 0.001
    priors = {"thickness_mm": 0.004, "gamma": 0.01, "eta": 0.004}  # small: the fit's linear regime
    means = {"thickness_mm": 0.25, "gamma": 0.75, "eta": skin.eta}
    bounds = info.band_bounds(bands, info.white_noise(sigma), [ROW], nuisances=priors)
    quadrature = spectral_quadrature(bands)
    rng = np.random.default_rng(31)
    theta = np.array([skin.C_m, skin.beta_m, skin.C_h_out, skin.C_h_in])
    names = list(priors)
    s = np.array([priors[k] for k in names])
    m = np.array([means[k] for k in names])
    estimates = []
    for _ in range(120):
        nuisance = m + s * rng.standard_normal(3)
        clean = quadrature_reflectance(quadrature, *theta, nuisance[1], nuisance[0], nuisance[2])
        observed = clean * (1.0 + sigma * rng.standard_normal(n))

        def residual(p):
            model = quadrature_reflectance(quadrature, *p[:4], p[5], p[4], p[6])
            return np.concatenate([(model - observed) / (sigma * observed), (p[4:] - m) / s])

        fit = least_squares(residual, np.concatenate([theta, m]), method="trf",
                            bounds=(np.r_[np.zeros(4), 0.05, 0.3, 1.2], np.r_[np.ones(4), 0.6, 1.0, 1.7]),
                            x_scale=np.r_[np.full(4, 0.01), s], diff_step=1e-6, xtol=1e-10, ftol=1e-10)
        estimates.append(fit.x[:4])
    spread = np.array(estimates).std(axis=0)
    np.testing.assert_allclose(spread / bounds.std[0], 1.0, atol=0.3)
    held = info.band_bounds(bands, info.white_noise(sigma), [ROW])
    assert spread[3] / held.std[0, 3] > 1.3


def test_a_common_noise_part_in_the_design_is_the_full_covariance(bands):
    """The design's subset information with a band-common part (Sherman-Morrison) against the
    band bound with the same noise as an explicit covariance matrix."""
    candidates = bandpass_bands([450, 500, 550, 600, 650], 10)
    noise = info.white_noise(0.01, common=0.02)
    priors = {"thickness_mm": 0.05, "gamma": 0.08, "eta": 0.015}
    design = info.design_bands(candidates, 5, noise, search="exhaustive", nuisances=priors)
    matrix = 0.01 ** 2 * np.eye(5) + 0.02 ** 2 * np.ones((5, 5))
    explicit = info.band_bounds(candidates, info.NoiseModel("covariance", matrix=matrix), nuisances=priors)
    assert design.value == pytest.approx(explicit.criterion("mean"), rel=1e-9)
    direct = info.band_bounds(candidates, noise, nuisances=priors)
    np.testing.assert_allclose(direct.std, explicit.std, rtol=1e-9)
    with pytest.raises(ValueError, match="band-common"):
        info.white_noise(0.01, relative=False, common=0.01)
