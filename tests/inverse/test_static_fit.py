"""The static stage's optimizer on in-memory texel-views of a sphere with known maps.

Recovery of known parameters (the model made the data, so any miss is the
fit's), the best-constant baseline, the ablations' switches, and exact
resumption after an interruption.
"""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from synthetic_texel_views import InMemoryStore, sphere_views

T = 32
BANDS = ("b0", "b1", "b2")


@pytest.fixture(scope="module")
def sphere_problem():
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono_polarized")
    from polarbssrdf.geometry import normals_from_height, texel_atlas, to_mitsuba, uv_sphere

    rng = np.random.default_rng(1)
    atlas = texel_atlas(to_mitsuba(uv_sphere(60.0, rings=48, segments=96)), T)

    def field(mean, std, low=-np.inf, high=np.inf):
        noise = gaussian_filter(rng.standard_normal((T, T)), T / 10, mode="wrap")
        return np.clip(mean + std * noise / noise.std(), low, high).astype(np.float32)

    # means away from the start values (eta 1.4, alpha_s 0.35), so a map
    # that does not move scores badly
    truth = {"eta": field(1.50, 0.04, 1.3, 1.6), "alpha_s": field(0.40, 0.05, 0.1, 0.7),
             "rho_s": field(0.8, 0.1), "rho_ss": field(0.3, 0.05),
             "alpha_ss": field(0.97, 0.01, 0.7, 1.0), "displacement": field(0.0, 0.1)}
    truth["normal"] = normals_from_height(truth["displacement"], atlas).astype(np.float32)
    rho_sss = np.stack([field(0.4, 0.05), field(0.6, 0.05), field(0.7, 0.05)])
    views = sphere_views(atlas, truth, rho_sss, n_cameras=12)
    return atlas, InMemoryStore(views, T, BANDS), truth, rho_sss


def _mae(recovered, truth, mask):
    return float(np.mean(np.abs(recovered - truth)[mask]))


def test_noise_free_sphere_recovers_eta_albedo_and_normals(sphere_problem):
    from polarbssrdf.inverse.config import static_config
    from polarbssrdf.inverse.static import run_polarimetric_fit

    atlas, store, truth, rho_sss = sphere_problem
    result = run_polarimetric_fit(store, atlas, static_config(iterations=150), progress=False)
    maps = result.maps
    scored = (maps["confidence"] > 0) & atlas.valid
    assert scored.sum() > 0.5 * atlas.valid.sum()
    eta_mae = _mae(maps["eta"], truth["eta"], scored)
    eta_constant = _mae(truth["eta"][scored].mean(), truth["eta"], scored)
    assert eta_mae < 0.02 and eta_mae < eta_constant / 2
    for band in range(len(BANDS)):
        relative = np.abs(maps[f"rho_sss.{BANDS[band]}"] - rho_sss[band]) / rho_sss[band]
        assert np.mean(relative[scored]) < 0.03
    normal = np.stack([maps[f"normal.{a}"] for a in "xyz"], axis=-1)
    angle = np.degrees(np.arccos(np.clip(np.sum(normal * truth["normal"], -1), -1, 1)))
    assert np.mean(angle[scored]) < 1.0
    # confidence 0 texels are filled, never NaN
    for name, values in maps.items():
        assert np.isfinite(values).all(), name
    # the loss went down
    assert result.history[-1]["total"] < 0.5 * result.history[0]["total"]


def test_without_polarimetric_losses_eta_is_not_recovered(sphere_problem):
    """Ablation switch: without L_psi and L_phi only the Fresnel reflectance constrains eta."""
    from polarbssrdf.inverse.config import static_config
    from polarbssrdf.inverse.static import run_polarimetric_fit

    atlas, store, truth, _ = sphere_problem
    full = run_polarimetric_fit(store, atlas, static_config(iterations=60), progress=False)
    ablated = run_polarimetric_fit(store, atlas, static_config(iterations=60, polarimetric=False),
                                   progress=False)
    scored = (full.maps["confidence"] > 0) & atlas.valid
    assert (_mae(ablated.maps["eta"], truth["eta"], scored)
            > 1.5 * _mae(full.maps["eta"], truth["eta"], scored))


def test_an_interrupted_fit_resumes_to_the_same_maps(sphere_problem, tmp_path, monkeypatch):
    import polarbssrdf.inverse.static as static
    from polarbssrdf.inverse.config import static_config

    atlas, store, _, _ = sphere_problem
    config = static_config(iterations=5)
    straight = static.run_polarimetric_fit(store, atlas, config, progress=False,
                                           checkpoint=tmp_path / "straight.npz")
    step, calls = static.optimizer_step, []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3 * config.min_steps_per_epoch + 2:  # inside epoch 4
            raise KeyboardInterrupt
        return step(*args, **kwargs)

    monkeypatch.setattr(static, "optimizer_step", interrupted)
    checkpoint = tmp_path / "resumed.npz"
    with pytest.raises(KeyboardInterrupt):
        static.run_polarimetric_fit(store, atlas, config, progress=False, checkpoint=checkpoint)
    monkeypatch.setattr(static, "optimizer_step", step)
    resumed = static.run_polarimetric_fit(store, atlas, config, progress=False,
                                          checkpoint=checkpoint)
    assert len(resumed.history) == len(straight.history) == 5
    for name, values in straight.maps.items():
        np.testing.assert_allclose(resumed.maps[name], values, atol=1e-5, err_msg=name)


def test_a_checkpoint_of_another_run_is_refused(sphere_problem, tmp_path):
    from polarbssrdf.inverse.config import static_config
    from polarbssrdf.inverse.static import run_polarimetric_fit

    atlas, store, _, _ = sphere_problem
    checkpoint = tmp_path / "checkpoint.npz"
    run_polarimetric_fit(store, atlas, static_config(iterations=1), progress=False,
                         checkpoint=checkpoint)
    with pytest.raises(ValueError, match="other settings"):
        run_polarimetric_fit(store, atlas, static_config(iterations=2, seed=3), progress=False,
                             checkpoint=checkpoint)
    # more epochs extend the run; fewer than the checkpoint holds cannot be had
    extended = run_polarimetric_fit(store, atlas, static_config(iterations=2), progress=False,
                                    checkpoint=checkpoint)
    assert len(extended.history) == 2
    with pytest.raises(ValueError, match="more than"):
        run_polarimetric_fit(store, atlas, static_config(iterations=1), progress=False,
                             checkpoint=checkpoint)
