"""GGX distribution and Smith masking: normalizations and Mitsuba's implementation."""

import numpy as np
import pytest
from scipy.integrate import quad

import mitsuba as mi
from polarbssrdf.optics import ggx_distribution, smith_g1_ggx

ALPHAS = [0.05, 0.3, 0.6, 1.0]


@pytest.mark.parametrize("alpha", ALPHAS)
def test_projected_area_normalization(alpha):
    """int D(h) cos(theta_h) d omega_h = 1."""
    value = quad(lambda t: 2 * np.pi * ggx_distribution(np.cos(t), alpha) * np.cos(t) * np.sin(t),
                 0, np.pi / 2, limit=400, points=[min(alpha, 1.0)])[0]
    assert value == pytest.approx(1.0, rel=1e-5)


@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("theta_v", [0.1, 0.7, 1.2, 1.5])
def test_visible_normal_normalization(alpha, theta_v):
    """Heitz 2014: int G1(v, h) <v, h>+ D(h) d omega_h = cos(theta_v)."""
    v = np.array([np.sin(theta_v), 0.0, np.cos(theta_v)])
    n_t, n_p = 600, 256
    t = (np.arange(n_t) + 0.5) / n_t * np.pi / 2
    p = (np.arange(n_p) + 0.5) / n_p * 2 * np.pi
    T, P = np.meshgrid(t, p, indexing="ij")
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)])
    vh = np.tensordot(v, h, axes=1)
    integrand = (smith_g1_ggx(np.full_like(vh, v[2]), vh, alpha) * np.maximum(vh, 0)
                 * ggx_distribution(h[2], alpha) * np.sin(T))
    value = integrand.sum() * (np.pi / 2 / n_t) * (2 * np.pi / n_p)
    assert value == pytest.approx(np.cos(theta_v), rel=2e-3)


def test_matches_mitsuba_microfacet_distribution(rng):
    mi.set_variant("llvm_ad_mono_polarized")
    n = 2000
    h = rng.normal(size=(n, 3))
    h[:, 2] = np.abs(h[:, 2])
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for alpha in ALPHAS:
        distr = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
        hm, vm = mi.Vector3f(h.T), mi.Vector3f(v.T)
        np.testing.assert_allclose(ggx_distribution(h[:, 2], alpha), np.array(distr.eval(hm)),
                                   rtol=2e-4)
        np.testing.assert_allclose(smith_g1_ggx(v[:, 2], np.sum(v * h, axis=1), alpha),
                                   np.array(distr.smith_g1(vm, hm)), rtol=2e-4, atol=1e-6)
