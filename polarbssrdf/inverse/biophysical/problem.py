"""The biophysical fit's problem: data, the band-integrated model with its nuisances, the noise.

The predicted lobe albedo of band ``b`` at a texel is

    A_b = rho_b(C_m, beta_m, C_h_out, C_h_in; t0, g0, eta0) (1 + sum_k J_bk dn_k),

``rho_b`` the band integral of eq. 46 through the texture-space layered blur
(:class:`~polarbssrdf.inverse.biophysical.model.BiophysicalModel`, the model synth
renders with) at the face's epidermal thickness ``t0``, oxygenation ``g0`` and the
index map ``eta0``, and ``dn_k`` the nuisance maps (:data:`NUISANCES`: thickness,
oxygenation and index, as deviations from those centres) entering to first order
through ``J_bk = d ln rho_b / d n_k``, the per-texel sensitivity of the unblurred
band-integrated albedo (:class:`NuisanceSensitivity`, by central differences of
:func:`~polarbssrdf.skin.quadrature.quadrature_reflectance`). The nuisances are smooth
and small (0.01 mm, 0.02, 0.015 within a face), so the second-order terms stay
below 0.1% of the albedo; the fit re-centres the index and re-linearizes between
rounds.

The prediction is then blurred as the capture blurs the maps fitted from it
(``blur_variance_mm2``; issue 32, item 3): a freckle finer than the pixels reaches the input
flattened, and a prediction compared sharp would explain the flattening by less melanin.

The data term is ``1/2 sum_i r_i^T S^-1 r_i / q_i^2`` over texels of the relative residuals
``r_b = (A_b - a_b) / a_b`` with covariance ``q_i^2 S``, ``S = diag(sigma^2) + common^2 1 1^T``
(:meth:`DataTerm.set_noise`) and ``q_i`` the texel's noise relative to the face's typical
texel (1 unless the input carries a per-texel std).
"""

from __future__ import annotations

import hashlib

import drjit as dr
import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.inverse.biophysical.config import NUISANCES
from polarbssrdf.inverse.biophysical.model import PARAMETERS, jit_types
from polarbssrdf.render.subsurface import subsurface_exit_fraction
from polarbssrdf.render.texture_diffusion import blur_sum_of_gaussians
from polarbssrdf.skin.quadrature import quadrature_reflectance

NUISANCE_STEPS = {"thickness_mm": 1e-3, "gamma": 1e-3, "eta": 1e-3}
"""Central-difference steps of the nuisance sensitivities (mm; fraction; index)."""


class NuisanceSensitivity:
    """``J_bk = d ln rho_b / d n_k`` per texel (n_bands, n_texels) for each nuisance ``k``.

    ``rho_b`` is the unblurred band-integrated lobe albedo (eq. 47 / c(eta)) of the model's
    quadrature at the chromophore ``maps`` (flat over the texels ``texels``), the face's
    thickness and oxygenation and the index map (flat)."""

    def __init__(self, quadrature, maps, texels, thickness_mm, gamma, eta):
        values = {n: np.ravel(maps[n])[texels].astype(np.float64) for n in PARAMETERS}
        eta = np.ravel(eta)[texels].astype(np.float64)
        centre = {"thickness_mm": float(thickness_mm), "gamma": float(gamma), "eta": eta}
        self.texels = texels
        self.size = np.ravel(maps[PARAMETERS[0]]).size
        self.relative = {}
        for name in NUISANCES:
            step = NUISANCE_STEPS[name]
            up, down = dict(centre), dict(centre)
            up[name] = centre[name] + step
            down[name] = centre[name] - step
            rho_up, rho_down = (self._albedo(quadrature, values, point) for point in (up, down))
            self.relative[name] = (np.log(rho_up) - np.log(rho_down)).T / (2.0 * step)  # (B, n)

    @staticmethod
    def _albedo(quadrature, values, point):
        reflectance = quadrature_reflectance(quadrature, values["C_m"], values["beta_m"], values["C_h_out"],
                                             values["C_h_in"], point["gamma"], point["thickness_mm"], point["eta"])
        return reflectance / subsurface_exit_fraction(point["eta"])[:, None]

    def full(self, name):
        """(n_bands, T*T) sensitivity of nuisance ``name``, 0 off ``texels``."""
        rows = self.relative[name]
        out = np.zeros((rows.shape[0], self.size))
        out[:, self.texels] = rows
        return out


def _maps_key(maps, names):
    """A digest of the maps a local Jacobian depends on (the chromophores, the nuisances, names)."""
    digest = hashlib.blake2b(repr(tuple(names)).encode(), digest_size=16)
    for name in PARAMETERS + tuple(NUISANCES):
        if name in maps:
            digest.update(name.encode())
            digest.update(np.ascontiguousarray(maps[name], dtype=np.float64).tobytes())
    return digest.hexdigest()


class DataTerm:
    """Eq. 41 over Dr.Jit parameter arrays: the predicted albedo (module docstring) and the
    loss ``1/2 sum_i r_i^T S^-1 r_i`` with the bands' noise ``S``.

    Parameters
    ----------
    model : BiophysicalModel
    observed : (n_bands, T, T) array
        The input lobe albedo (filled at flagged texels).
    weight : (T, T) array
        ``1 / q`` where a texel enters the data term, its noise ``q`` times the bands' noise
        ``S`` (1 for the face's typical texel; :func:`~.fit.texel_noise_scale`), 0 where it
        does not (flagged).
    sigma, common : the starts of the noise (:meth:`set_noise`).
    blur_variance_mm2 : float
        The capture's blur of the input maps as one Gaussian (mm^2,
        :func:`~polarbssrdf.inverse.observations.footprint.capture_blur_variance_mm2`): the
        prediction is blurred so before it meets the input; 0: the input is sharp.
    """

    def __init__(self, model, observed, weight, sigma, common, blur_variance_mm2=0.0):
        Float, _, _ = jit_types()
        self.model = model
        self.blur_variance_mm2 = float(blur_variance_mm2)
        self.observed_numpy = observed
        self.weight = weight
        self.observed = [to_jit(Float, observed[b].ravel(), np.float32) for b in range(len(model.bands))]
        self.sensitivity = None
        self._sensitivity_jit = {}
        self._jacobian_cache = None
        self.set_noise(sigma, common)

    def set_sensitivity(self, sensitivity):
        """Use these nuisance sensitivities (:class:`NuisanceSensitivity`) from now on."""
        Float, _, _ = jit_types()
        self.sensitivity = sensitivity
        self._jacobian_cache = None
        self._sensitivity_jit = {name: [to_jit(Float, row, np.float32) for row in sensitivity.full(name)]
                                 for name in NUISANCES}

    def set_noise(self, sigma, common):
        """Set the bands' own relative noise ``sigma`` (n_bands,), the band-common relative
        noise ``common`` and the data term's weights.

        Per texel the relative residuals ``r`` have covariance ``diag(sigma^2) +
        common^2 1 1^T``; in ``z_b = r_b / sigma_b`` its inverse is ``I - kappa v v^T``
        with ``v_b = 1 / sigma_b`` and ``kappa = 1 / (1 / common^2 + sum_b v_b^2)``
        (Sherman-Morrison)."""
        Float, _, _ = jit_types()
        self.sigma = np.asarray(sigma, np.float64)
        self.common = float(common)
        scale = self.weight[None] / (self.sigma[:, None, None] * np.maximum(self.observed_numpy, 1e-3))
        self.scale_numpy = scale.reshape(len(self.sigma), -1)
        self.scale = [to_jit(Float, row, np.float32) for row in self.scale_numpy]
        self.v = 1.0 / self.sigma
        self.kappa = 0.0 if self.common <= 0 else 1.0 / (1.0 / self.common ** 2 + float(np.sum(self.v ** 2)))
        # they change every round: kernel inputs, not literals
        self._v_jit = [dr.opaque(Float, float(v)) for v in self.v]
        self._kappa_jit = dr.opaque(Float, self.kappa)

    def nuisance_factor(self, params, band):
        """``1 + sum_k J_bk dn_k`` (flat Float) for the nuisance maps in ``params``, or None."""
        factor = None
        for name in NUISANCES:
            if name in params and name in self._sensitivity_jit:
                term = self._sensitivity_jit[name][band] * params[name]
                factor = term if factor is None else factor + term
        return None if factor is None else 1.0 + factor

    def predict(self, params):
        """Per band, the predicted albedo ``A_b`` (flat Float) of the maps in ``params``, seen
        through the capture's blur."""
        _, _, TensorXf = jit_types()
        values = self.model.render_bands(params)
        atlas = self.model.atlas
        out = []
        for b, value in enumerate(values):
            factor = self.nuisance_factor(params, b)
            value = value if factor is None else value * factor
            if self.blur_variance_mm2 > 0:
                value = blur_sum_of_gaussians(TensorXf(value, self.model.shape), (1.0,), (self.blur_variance_mm2,),
                                              atlas.texel_size_mm, atlas.valid).array
            out.append(value)
        return out

    def __call__(self, params, predicted=None):
        Float, _, _ = jit_types()
        predicted = predicted or self.predict(params)
        loss = Float(0.0)
        common = Float(0.0)
        for b, value in enumerate(predicted):
            z = (value - self.observed[b]) * self.scale[b]
            loss += 0.5 * dr.sum(z * z)
            common += z * self._v_jit[b]
        loss -= 0.5 * self._kappa_jit * dr.sum(common * common)
        return loss

    def local_jacobian(self, maps, names):
        """``(n_texels, n_bands, len(names))`` d(predicted albedo)/d(map) of the unblurred model.

        Chromophores by Dr.Jit forward mode through the band-integrated local albedo
        (times the nuisance factor), nuisances as the local albedo times their
        sensitivity."""

        Float, _, _ = jit_types()
        key = (_maps_key(maps, names), self.model.thickness_mm, self.model.gamma)
        if self._jacobian_cache is not None and self._jacobian_cache[0] == key:
            return self._jacobian_cache[1]
        params = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in PARAMETERS}
        nuisance_params = {n: to_jit(Float, np.ravel(maps[n]), np.float32) for n in NUISANCES if n in maps}
        factors = [self.nuisance_factor(nuisance_params, b) for b in range(len(self.model.bands))]
        factors = [1.0 if f is None else np.array(f, dtype=np.float64) for f in factors]
        local = None
        columns = []
        for name in names:
            if name in NUISANCES:
                if local is None:
                    local = self.model.band_sums_numpy(self.model.local_albedo_nodes(params))
                sensitivity = self.sensitivity.full(name)
                columns.append(np.stack([local[b] * sensitivity[b] for b in range(len(local))], axis=-1))
                continue
            dr.enable_grad(params[name])
            nodes = self.model.local_albedo_nodes(params)
            dr.forward(params[name])
            # node by node: every node's derivative is then the same compiled kernel
            derivatives = []
            for value in nodes:
                derivative = dr.grad(value)
                dr.eval(derivative)
                derivatives.append(derivative)
            bands = self.model.band_sums_numpy(derivatives)
            columns.append(np.stack([bands[b] * factors[b] for b in range(len(bands))], axis=-1))
            dr.disable_grad(params[name])
        jacobian = np.stack(columns, axis=-1)
        jacobian.flags.writeable = False
        # a round's noise, spread and posterior and the next round's first step all ask at
        # the same maps: four forward passes over every node each time otherwise
        self._jacobian_cache = (key, jacobian)
        return jacobian

    def precision(self, maps, names, movable):
        """``(n, k, k)`` Gauss-Newton normal matrix ``J_z^T (I - kappa v v^T) J_z`` of the
        movable texels (``J_z`` the Jacobian in the data term's ``z`` units), and ``J_z``."""
        J = self.local_jacobian(maps, names)[movable] * self.scale_numpy[:, movable].T[:, :, None]
        return self.precision_from_jacobian(J), J

    def precision_from_jacobian(self, J):
        """The data precision per texel from ``J_z`` (:meth:`precision`'s second output)."""
        projected = np.einsum("nbi,b->ni", J, self.v)
        return np.einsum("nbi,nbj->nij", J, J) - self.kappa * np.einsum("ni,nj->nij", projected, projected)
