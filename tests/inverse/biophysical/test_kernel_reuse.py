"""The biophysical fit compiles its kernels once: an identical rerun compiles none, nor do other bands.

A value that changes between calls and is baked into a kernel as a literal
(a table origin, a fitted SoG weight, a loss normalization), or a NumPy buffer
handed to Dr.Jit at another alignment, makes a kernel hash anew and compiles
again (bench/bench_kernels.py finds them). Read from Dr.Jit's kernel history.
"""

import drjit as dr
import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.spectral import default_bands

T = 32


@pytest.fixture(scope="module")
def face():
    from polarbssrdf.geometry import face_mesh, texel_atlas, to_mitsuba
    from polarbssrdf.synth.synthesize import subsurface_albedo
    from polarbssrdf.synth.truth import TruthSettings, truth_maps

    mi.set_variant("llvm_ad_mono_polarized")
    atlas = texel_atlas(to_mitsuba(face_mesh(1)), T)
    layers = {"thickness_mm": (0.25, 0.0, 0.10, 0.40), "gamma": (0.75, 0.0, 0.50, 0.95)}  # the model's
    maps = truth_maps(atlas, TruthSettings(skin=("cheek", "IV"), skin_layers=layers), np.random.default_rng(1))
    bands = default_bands()
    return atlas, bands, maps, subsurface_albedo(maps, bands)


def albedo_maps(face, seed):
    """The face's truth albedo with 1% multiplicative noise of ``seed``, as fresh NumPy arrays."""
    _, bands, maps, albedo = face
    noisy = albedo * (1.0 + 0.01 * np.random.default_rng(seed).standard_normal(albedo.shape))
    inputs = {f"rho_sss.{b.name}": noisy[i].copy() for i, b in enumerate(bands)}
    inputs["eta"] = maps["eta"].copy()
    return inputs


def compiled_kernels(run):
    """(result of ``run()``, kernels it launched, hashes of those not in Dr.Jit's in-memory cache).

    A kernel not in memory was compiled or loaded from ``~/.drjit`` (``cache_disk``): either
    way this process had not used it before, so the test does not depend on the disk cache."""
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history_clear()
        result = run()
        history = dr.kernel_history([dr.KernelType.JIT])
    return result, len(history), sorted({h["hash"] for h in history
                                         if not h["cache_hit"] or h["cache_disk"]})


def test_an_identical_rerun_compiles_no_new_kernel(face):
    from polarbssrdf.inverse.biophysical.fit import BiophysicalConfig, fit_biophysical

    atlas, bands, _, _ = face
    config = BiophysicalConfig(iterations=3, rounds=2, kernel_tolerance=0.0)

    def fit():
        return fit_biophysical(albedo_maps(face, 1), bands, atlas, config)

    first = fit()
    rerun, launched, compiled = compiled_kernels(fit)
    assert launched > 100  # the fit does run on Dr.Jit
    assert compiled == [], f"an identical rerun compiled {len(compiled)} of {launched} kernels anew"
    for name in first.maps:  # and it is deterministic
        np.testing.assert_array_equal(rerun.maps[name], first.maps[name])


def test_every_node_and_other_maps_reuse_the_models_kernels(face):
    """The chromophore basis and the table origins differ per quadrature node (and per run):
    kernel inputs, so once one node's layer totals are compiled, the others compile nothing;
    and the band sums of the nodes without the blur are synth's lobe albedo (eq. 47 / c(eta))."""
    from polarbssrdf._arrays import to_jit
    from polarbssrdf.inverse.biophysical.model import PARAMETERS, BiophysicalModel, jit_types

    atlas, bands, maps, albedo = face
    Float, _, _ = jit_types()
    model = BiophysicalModel(bands, atlas, maps["eta"])

    def totals(values, node):
        params = {n: to_jit(Float, values[n].ravel(), np.float32) for n in PARAMETERS}
        out = model.layer_totals(node, params)
        dr.eval(*out)
        return [np.array(v) for v in out]

    totals(maps, 0)
    other = {n: maps[n] * 0.9 for n in PARAMETERS}
    _, launched, compiled = compiled_kernels(lambda: [totals(other, node) for node in range(1, model.nodes)])
    assert model.nodes > len(bands) and launched >= model.nodes - 1
    assert compiled == [], f"{len(compiled)} of {launched} kernels compiled anew for other nodes"
    params = {n: to_jit(Float, maps[n].ravel(), np.float32) for n in PARAMETERS}
    local = [np.array(v).reshape(atlas.valid.shape) for v in model.local_albedo_bands(params)]
    surface = atlas.valid
    for b in range(len(bands)):  # to the tables' interpolation error
        np.testing.assert_allclose(local[b][surface], albedo[b][surface], rtol=1e-4)


def test_the_jacobian_compiles_nothing_for_other_bands(face):
    """The local Jacobian reads each quadrature node's forward derivative on its own
    (:meth:`~polarbssrdf.inverse.biophysical.model.BiophysicalModel.local_albedo_nodes`),
    and the nodes share their kernels: after one model's Jacobian, a model of other bands
    (another quadrature, another number of nodes per band) compiles no kernel for its own.
    Summed per band in Dr.Jit, the kernels followed each band's nodes."""
    from polarbssrdf.inverse.biophysical.model import PARAMETERS, BiophysicalModel
    from polarbssrdf.inverse.biophysical.problem import DataTerm
    from polarbssrdf.spectral.bands import bandpass_bands

    atlas, bands, maps, albedo = face

    def jacobian(bands):
        model = BiophysicalModel(bands, atlas, maps["eta"])
        observed = np.full((len(bands),) + atlas.valid.shape, 0.4)
        term = DataTerm(model, observed, atlas.valid.astype(np.float64), np.full(len(bands), 0.01), 0.0)
        return model, term.local_jacobian({n: maps[n] for n in PARAMETERS}, PARAMETERS)

    first_model, first = jacobian(bands)
    other = bandpass_bands([430.0, 500.0, 560.0, 620.0, 680.0], 30.0)
    (model, second), launched, compiled = compiled_kernels(lambda: jacobian(other))
    assert model.nodes != first_model.nodes and second.shape[1:] == (len(other), len(PARAMETERS))
    assert np.all(np.isfinite(second)) and np.any(second != 0.0)
    assert compiled == [], f"the other bands' Jacobian compiled {len(compiled)} of {launched} kernels"


def test_no_kernel_of_a_fit_traces_the_tables_of_every_node(face):
    """The layer totals enter the derivatives as their evaluated slopes times ``d ln
    sigma_a`` (:meth:`~polarbssrdf.inverse.biophysical.model.BiophysicalModel.layer_totals`),
    so no kernel of a fit grows with the table lookups of all the bands' nodes: the largest is
    below 2,500 operations. Traced through the tables, the Jacobian's and the gradient's
    kernels reached 5,933 operations on the default bands, each 2-9 s of LLVM on a cold
    kernel cache (bench/RESULTS.md, 2026-12-08)."""
    from polarbssrdf.inverse.biophysical.fit import BiophysicalConfig, fit_biophysical

    atlas, bands, _, _ = face
    config = BiophysicalConfig(iterations=3, rounds=2, kernel_tolerance=0.0)
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history_clear()
        fit_biophysical(albedo_maps(face, 2), bands, atlas, config)
        history = dr.kernel_history([dr.KernelType.JIT])
    assert len(history) > 100
    largest = max(entry["operation_count"] for entry in history)
    assert largest < 2500, f"a kernel of {largest} operations"
