"""The biophysical stage's prior and the posterior spread it leads to (issue 20, items 3-4).

Each chromophore map ``x`` is a Gaussian Markov random field around a face
mean ``mu``: a Matérn field of Lindgren, Rue and Lindström (J. R. Stat. Soc.
B 73, 2011, eq. 2), the solution of ``(1 - l^2 Laplacian)^(alpha/2) x = white
noise``, on the texel grid. Its negative log density is

    1/2 (x - mu)^T Q (x - mu),   Q = W A^order / tau^2 (order 1),  A^T W A / tau^2 (order 2),

``A = I + l^2 W^-1 L``, with ``W`` the texel areas (mm^2), ``L`` the graph
Laplacian of neighbouring surface texels (pair weight ``h_perp / h_along``,
so ``W^-1 L`` is the Laplacian in mm^-2) and ``l`` the correlation length
(mm). The fit uses order 2 by default (``prior_order``): smooth at the texel
scale, it pools the data of a few correlation lengths. Its precision's
condition number grows as ``(l / h)^4``; block-Jacobi conjugate gradients do
not converge at 128^2 and up and a sparse direct solve took 65-143 s per step
at 256^2, so the steps are preconditioned in the Fourier domain
(:class:`FourierPreconditioner`). Its marginal
standard deviation is the within-face spread ``s``
(:func:`precision_scale`). The face mean has a hyperprior: Gaussian around
the mean of Table 2's eight rows with their spread across rows
(:func:`population_prior`), so a chromophore the bands cannot tell falls back
to a constant at the face's best-supported mean, and a face off the Table 2
means is free to say so where the data speak.

Posterior spread (:func:`posterior_covariance`): for a texel whose data
precision ``C`` (k x k, the Gauss-Newton normal matrix of its bands) is
locally constant, the posterior covariance of a stationary field is the
average over spatial frequencies of ``(C + q(omega))^-1``, with ``q`` the
prior's symbol ``area (1 + l^2 lambda / area)^order / tau^2`` (``lambda`` the
lattice Laplacian's symbol), averaged over the lattice spectrum binned in
``ln lambda``; the face mean's own uncertainty is added through the constant
mode (:func:`mean_mode_covariance`).
"""

from __future__ import annotations

import numpy as np
from scipy import fft, sparse
from scipy.stats import chi2

from polarbssrdf._arrays import masked_low_pass
from polarbssrdf._linalg import batched_spd_inverse
from polarbssrdf.skin.parameters import TABLE2, TABLE2_STD

DEFAULT_CORRELATION_MM = 5.0
"""Correlation length of the chromophore fields (mm): melanin and blood vary over
millimetres to centimetres on a face (freckles, flushing), not from texel to texel."""

SPECTRUM_BINS = 48
"""Bins (in ``ln lambda``) of the lattice spectrum :func:`posterior_covariance` averages over."""


def population_prior(names=("C_m", "beta_m", "C_h_out", "C_h_in")):
    """``name -> (mean, std)`` of a face's mean value: the mean and the spread (ddof 0) of
    Table 2's eight rows (supplement Table 2; volume fractions)."""

    return {n: (float(np.mean([getattr(p, n) for p in TABLE2.values()])),
                float(np.std([getattr(p, n) for p in TABLE2.values()]))) for n in names}


def within_face_spread(names=("C_m", "beta_m", "C_h_out", "C_h_in")):
    """``name -> std`` of a chromophore over one face region: the mean over Table 2's rows of
    their "(std)" (supplement Table 2; volume fractions)."""

    return {n: float(np.mean([row[n] for row in TABLE2_STD.values()])) for n in names}


def precision_scale(std, correlation_mm, area_mm2, order=1):
    """``tau^2`` of ``Q = A^T W A / tau^2`` whose marginal standard deviation is ``std``.

    The prior alone has variance ``tau^2 / area`` times
    :func:`prior_variance_factor` (:func:`posterior_covariance` with ``C = 0``),
    about ``tau^2 / (area + 4 pi l^2)`` for ``l`` well above the texel size.
    ``area_mm2``: a typical texel's area (the median)."""

    return float(std) ** 2 * float(area_mm2) / float(prior_variance_factor(correlation_mm, area_mm2, order))


def neighbour_pairs(surface, texel_size_mm):
    """``(first, second, weight)`` of horizontally and vertically neighbouring surface texels
    (flat indices into the (T, T) grid); ``weight = h_perp / h_along`` (dimensionless)."""

    T = surface.shape[0]
    index = np.arange(T * T).reshape(T, T)
    sizes = np.asarray(texel_size_mm, np.float64).reshape(T * T, 2)
    flat = surface.ravel()
    firsts, seconds, weights = [], [], []
    for along, (a, b) in enumerate(((index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :]))):
        a, b = a.ravel(), b.ravel()
        both = flat[a] & flat[b]
        a, b = a[both], b[both]
        h_along = 0.5 * (sizes[a, along] + sizes[b, along])
        h_perp = 0.5 * (sizes[a, 1 - along] + sizes[b, 1 - along])
        firsts.append(a)
        seconds.append(b)
        weights.append(h_perp / np.maximum(h_along, 1e-9))
    return np.concatenate(firsts), np.concatenate(seconds), np.concatenate(weights)


class SpatialPrior:
    """The unit Matérn precision over the surface texels (see the module docstring).

    Parameters
    ----------
    surface : (T, T) bool
    texel_size_mm : (T, T, 2) float
        Texel extent along u and v (mm), the atlas's ``texel_size_mm``.
    correlation_mm : float
        Correlation length ``l``.
    order : {1, 2}
        ``alpha`` of the Matérn field (module docstring).

    Attributes
    ----------
    index : (n,) int
        Flat grid index of each surface texel (the prior's unknowns, in this order).
    area : (n,) float
        Texel areas (mm^2).
    unit : (n, n) sparse
        ``W A`` (order 1) or ``A^T W A`` (order 2); divide by ``tau^2`` for a map's precision.
    pairs : tuple
        ``(first, second, weight)`` of the neighbouring texels (positions among the unknowns)
        and their Laplacian weight (:func:`neighbour_pairs`).
    """

    def __init__(self, surface, texel_size_mm, correlation_mm=DEFAULT_CORRELATION_MM, order=2):
        if order not in (1, 2):
            raise ValueError(f"order must be 1 or 2, got {order!r}")
        self.order = int(order)
        if not correlation_mm > 0:
            raise ValueError(f"correlation_mm must be > 0, got {correlation_mm!r}")
        surface = np.asarray(surface, bool)
        self.shape = surface.shape
        self.correlation_mm = float(correlation_mm)
        self.index = np.flatnonzero(surface.ravel())
        n = len(self.index)
        sizes = np.asarray(texel_size_mm, np.float64).reshape(-1, 2)[self.index]
        self.area = np.maximum(sizes[:, 0] * sizes[:, 1], 1e-12)
        self.texel_area = float(np.median(self.area))
        position = np.full(surface.size, -1)
        position[self.index] = np.arange(n)
        first, second, weight = neighbour_pairs(surface, texel_size_mm)
        self.pairs = (position[first], position[second], weight)
        self.unit = self.coupled_unit(np.ones(len(weight)))

    def coupled_unit(self, coupling, weights=None):
        """The unit precision with each neighbour pair's Laplacian weight times ``coupling``
        (n_pairs,) in [0, 1]: 1 everywhere gives :attr:`unit`, 0 cuts the pair (a line
        process: the field may jump there). ``weights`` (n,), order 2: each texel's innovation
        precision, ``A^T W diag(weights) A`` (a scale mixture: a texel of weight ``w`` may
        depart by ``1 / sqrt(w)`` times the field's spread)."""
        a, b, weight = self.pairs
        n = len(self.index)
        weight = weight * np.asarray(coupling, np.float64)
        degree = np.bincount(a, weights=weight, minlength=n) + np.bincount(b, weights=weight, minlength=n)
        off = sparse.coo_matrix((-weight, (a, b)), shape=(n, n))
        laplacian = (off + off.T + sparse.diags(degree)).tocsr()
        l2 = self.correlation_mm ** 2
        if self.order == 1:
            return (sparse.diags(self.area) + l2 * laplacian).tocsr()
        if weights is not None:
            operator = sparse.identity(n) + l2 * sparse.diags(1.0 / self.area) @ laplacian
            return (operator.T @ sparse.diags(self.area * np.asarray(weights, np.float64)) @ operator).tocsr()
        inverse_area = sparse.diags(1.0 / self.area)
        return (sparse.diags(self.area) + 2.0 * l2 * laplacian
                + l2 * l2 * (laplacian @ inverse_area @ laplacian)).tocsr()

    def texel_coupling(self, coupling):
        """(n,) the mean ``coupling`` of each texel's pairs, weighted as the Laplacian weighs them
        (1 for a texel without pairs): its correlation length is ``l sqrt(mean)`` as far as the
        posterior's local stationarity goes (:func:`posterior_covariance`)."""
        a, b, weight = self.pairs
        n = len(self.index)
        total = np.bincount(a, weights=weight, minlength=n) + np.bincount(b, weights=weight, minlength=n)
        coupled = weight * np.asarray(coupling, np.float64)
        kept = np.bincount(a, weights=coupled, minlength=n) + np.bincount(b, weights=coupled, minlength=n)
        return np.where(total > 0, kept / np.maximum(total, 1e-30), 1.0)

    def texel_couplings(self, couplings):
        """(n, k) :meth:`texel_coupling` of each column of ``couplings`` (n_pairs, k)."""
        return np.stack([self.texel_coupling(c) for c in np.asarray(couplings).T], axis=-1)

    def tau2(self, std):
        """``tau^2`` of a map whose marginal spread is ``std`` (:func:`precision_scale`)."""
        return precision_scale(std, self.correlation_mm, self.texel_area, self.order)

    def energy(self, deviation, tau2):
        """``1/2 d^T Q d`` and its gradient ``Q d`` for a deviation ``d`` (n,) from the mean."""
        gradient = (self.unit @ deviation) / tau2
        return 0.5 * float(deviation @ gradient), gradient


FEATURE_SCALE_TEXELS = 1.5
"""Gaussian sigma (texels) of the surroundings a texel's albedo is compared with to find a
local feature (:func:`feature_coupling`): a feature is a few texels across, the finest
detail a map holds."""


def feature_probability(squared, dimensions, fraction, spread):
    """Posterior probability that a texel is a local feature, given its standardized departure.

    Spike and slab (George and McCulloch, J. Am. Stat. Assoc. 88, 1993): a texel is a feature
    with prior probability ``fraction``, and then departs in each of ``dimensions``
    standardized coordinates with ``spread`` times the typical texel's standard deviation;
    else with 1. ``squared`` is the departure's squared length. The likelihood ratio is
    ``spread^-d exp(m / 2 (1 - 1 / spread^2))``."""
    squared = np.asarray(squared, np.float64)
    log_ratio = (-float(dimensions) * np.log(spread) + 0.5 * squared * (1.0 - 1.0 / spread ** 2)
                 + np.log(fraction) - np.log1p(-fraction))
    return 1.0 / (1.0 + np.exp(-np.clip(log_ratio, -700.0, 700.0)))


def feature_coupling(albedo, good, spatial, jacobian, fraction, spread, scale_texels=FEATURE_SCALE_TEXELS):
    """``(weights (n, k), coupling (n_pairs, k))`` of each texel and neighbour pair of
    ``spatial`` for each of k maps (:meth:`SpatialPrior.coupled_unit`): a local feature frees
    the prior of the maps there, around and inside it.

    A freckle or a mole is a few texels whose melanin differs from the skin around by far
    more than the skin's smooth variation: a Gaussian field shrinks it into its surroundings
    and its std does not say so (issue 32, item 3). Per texel, the albedo's departure from
    its surroundings, ``d_b = ln a_b - G * ln a_b`` (``G`` a Gaussian of ``scale_texels``
    over the ``good`` texels), is projected on what the maps can make, the span of the
    texel's relative Jacobian ``J`` (``d ln a_b / d x_m``): its squared length there, ``m = d^T
    J (J^T J)^-1 J^T d``, is ``sigma^2 chi^2_k`` for noise alone, and is set against the
    typical texel's (its median over the ``good`` texels over chi^2_k's). The probability
    ``p`` that the texel is a feature (:func:`feature_probability`, k coordinates) frees
    every map there: the bands cannot tell which map a small spot is. The texel's weight,
    its innovation's precision, is the spike and slab's expected precision ``1 - p + p /
    spread^2``: a feature may depart from the field by ``spread`` times its spread, a texel
    that is not one keeps the Gaussian field. A pair's coupling is the smaller weight of its
    texels (a cut pair is Geman and Geman's line process, IEEE PAMI 6, 1984): the departure
    may be sharp. Texels outside ``good`` weigh 1.

    Parameters
    ----------
    albedo : (B, T, T)
        The input albedo per band (> 0).
    good : (T, T) bool
        Texels whose albedo enters the data term.
    spatial : SpatialPrior
    jacobian : (n, B, k)
        ``d ln a_b / d x_m`` at each of ``spatial``'s texels.
    fraction, spread : float
        The spike and slab's prior share of feature texels and their departure's spread.
    scale_texels : float
    """
    jacobian = np.asarray(jacobian, np.float64)
    k = jacobian.shape[-1]
    log_albedo = np.log(np.maximum(np.asarray(albedo, np.float64), 1e-6))
    departure = np.stack([(band - masked_low_pass(band, good, scale_texels)).ravel()[spatial.index]
                          for band in log_albedo], axis=-1)  # (n, B)
    usable = np.ravel(good)[spatial.index]
    if not usable.any():
        return np.ones((len(spatial.index), k)), np.ones((len(spatial.pairs[0]), k))
    normal = np.einsum("nbi,nbj->nij", jacobian, jacobian)
    normal += 1e-9 * np.einsum("nii->n", normal)[:, None, None] / k * np.eye(k)
    projected = np.einsum("nbi,nb->ni", jacobian, departure)
    squared = np.einsum("ni,ni->n", projected, np.linalg.solve(normal, projected[..., None])[..., 0])
    # the typical texel's: noise alone makes the squared length sigma^2 chi^2_k
    typical = max(float(np.median(squared[usable])) / chi2.ppf(0.5, k), 1e-30)
    probability = np.where(usable, feature_probability(squared / typical, k, fraction, spread), 0.0)
    weight = np.repeat((1.0 - probability + probability / spread ** 2)[:, None], k, axis=1)
    a, b, _ = spatial.pairs
    return weight, np.minimum(weight[a], weight[b])


_ZONE = {}
_SPECTRUM = {}


def _zone_bins(bins, grid):
    """``(theta, which, count)``: the ``grid`` midpoints of (0, pi) per axis (the Brillouin
    zone by symmetry), the ``ln lambda`` bin of each of the ``grid^2`` frequencies (flat)
    and the frequencies per bin. Cached per ``(bins, grid)``."""

    key = (int(bins), int(grid))
    if key not in _ZONE:
        theta = (np.arange(grid) + 0.5) * np.pi / grid
        half = np.sin(theta / 2.0) ** 2
        values = 4.0 * (half[:, None] + half[None, :]).ravel()
        edges = np.geomspace(values.min(), 8.0 + 1e-9, int(bins) + 1)
        which = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, int(bins) - 1)
        count = np.bincount(which, minlength=int(bins)).astype(np.float64)
        _ZONE[key] = (theta, which, count)
    return _ZONE[key]


def _bin_average(values, bins, grid):
    """Average per non-empty ``ln lambda`` bin of ``values`` over the zone's ``grid^2``
    frequencies (flat, in :func:`_zone_bins`' order)."""
    _, which, count = _zone_bins(bins, grid)
    total = np.bincount(which, weights=values, minlength=int(bins))
    keep = count > 0
    return total[keep] / count[keep]


def lattice_spectrum(bins=SPECTRUM_BINS, grid=1024):
    """Nodes and weights ``(lambda, weight)`` of the square lattice Laplacian's spectrum.

    ``lambda = 4 (sin^2(theta_u / 2) + sin^2(theta_v / 2))`` (the unit-spacing
    5-point Laplacian's symbol, in [0, 8]) over the Brillouin zone, binned in
    ``ln lambda``: ``sum weight f(lambda)`` is the zone average of a function
    smooth in ``ln lambda``. Cached per ``(bins, grid)``: every posterior and prior
    energy evaluates over it."""

    key = (int(bins), int(grid))
    if key not in _SPECTRUM:
        theta, _, count = _zone_bins(bins, grid)
        half = np.sin(theta / 2.0) ** 2
        values = 4.0 * (half[:, None] + half[None, :]).ravel()
        _SPECTRUM[key] = (_bin_average(values, bins, grid), count[count > 0] / values.size)
    return _SPECTRUM[key]


def prior_variance_factor(correlation_mm, area_mm2, order=1):
    """Zone average of ``1 / (1 + l^2 lambda / area)^order``: the prior's marginal variance is this
    times ``tau^2 / area``."""

    lam, weight = lattice_spectrum()
    area = np.asarray(area_mm2, np.float64)
    return np.sum(weight[:, None] / (1.0 + float(correlation_mm) ** 2 * lam[:, None] / np.ravel(area)[None, :]) ** order,
                  axis=0).reshape(area.shape)


def noise_spectrum(correlation, bins=SPECTRUM_BINS, grid=1024):
    """The noise's power spectrum ``S`` relative to white noise, per node of :func:`lattice_spectrum`.

    ``correlation``: ``(dy, dx) -> rho`` the noise's correlation between texels
    ``(dy, dx)`` apart (``(0, 0)`` is 1), measured on the fit's whitened
    residuals (:func:`~polarbssrdf.inverse.biophysical.fit.residual_correlation`).
    Made symmetric in the sign of each offset, ``S(theta) = sum rho(dy, dx) cos(dy
    theta_u) cos(dx theta_v)`` (the Wiener-Khinchin theorem on the lattice) is averaged
    over the texel frequencies of each ``ln lambda`` bin of :func:`lattice_spectrum`,
    after clipping at 0 (a measured correlation need not be positive definite). Unclipped,
    its zone average is 1 (the variance is kept); white noise gives 1 everywhere."""

    radius = max(max(abs(dy), abs(dx)) for dy, dx in correlation)
    rho = np.zeros((radius + 1, radius + 1))
    counts = np.zeros_like(rho)
    for (dy, dx), value in correlation.items():
        rho[abs(dy), abs(dx)] += value
        counts[abs(dy), abs(dx)] += 1
    rho = np.where(counts > 0, rho / np.maximum(counts, 1), 0.0)
    rho[0, 0] = 1.0
    theta, _, _ = _zone_bins(bins, grid)
    lags = np.arange(radius + 1)
    # both signs of a non-zero offset: cos(d theta) twice
    cosines = np.cos(theta[:, None] * lags[None, :]) * np.where(lags == 0, 1.0, 2.0)[None, :]
    return _bin_average(np.maximum(cosines @ rho @ cosines.T, 0.0).ravel(), bins, grid)


def capture_gain(area_mm2, blur_variance_mm2):
    """``|K(lambda)|^2`` (bins, n) of the capture's Gaussian blur over the lattice spectrum's nodes,
    or None without a blur.

    A Gaussian of variance ``v`` (mm^2) has the symbol ``exp(-v omega^2 / 2)``; on texels of
    area ``a`` the lattice's ``lambda`` is ``omega^2 a`` to second order, so the data's power
    at ``lambda`` is scaled by ``exp(-v lambda / a)``
    (:func:`~polarbssrdf.inverse.observations.footprint.capture_blur_variance_mm2`)."""
    if not blur_variance_mm2:
        return None
    lam, _ = lattice_spectrum()
    area = np.asarray(area_mm2, np.float64)[None, :]
    return np.exp(-float(blur_variance_mm2) * lam[:, None] / area)


def posterior_covariance(data_precision, area_mm2, tau2, correlation_mm, order=1, spectrum=None, gain=None):
    """Per-texel posterior covariance ``(n, k, k)`` of k Matérn maps given local data precision.

    Parameters
    ----------
    data_precision : (n, k, k)
        ``C``, the Gauss-Newton normal matrix of each texel's data (in the maps' units^-2).
    area_mm2 : (n,)
        Texel areas.
    tau2 : (k,)
        The maps' ``tau^2`` (:func:`precision_scale`), finite.
    correlation_mm : float or (n, k)
        Per texel and map for priors freed at features (:func:`feature_coupling`): the
        texel's own, as if it held everywhere (local stationarity, a stated approximation);
        then solved per frequency (:func:`_local_posterior`), where ``tau2`` may be per
        texel too, (n, k).
    order : {1, 2}
        The prior's order (:class:`SpatialPrior`).
    gain : (bins, n), optional
        :func:`capture_gain`: the data seen through the capture's blur, ``|K|^2 C`` per
        frequency (a detail finer than the blur is told by the prior alone).

    Returns the zone average of ``(C + diag(area (1 + l^2 lambda / area)^order / tau^2))^-1``
    over the lattice spectrum (:func:`lattice_spectrum`): exact for a field on
    an unbounded grid of equal square texels and data constant in space; a
    texel at the surface's edge (fewer neighbours) is more uncertain than this
    says. Excludes the face mean's own uncertainty (:func:`mean_mode_covariance`).

    With ``spectrum`` (:func:`noise_spectrum`: data noise correlated between
    texels, power ``s`` per frequency relative to white) the covariance of the
    posterior mode's error is the sandwich ``(C + Q)^-1 (s C + Q) (C + Q)^-1``
    per frequency (the fit still weighs the data as white; for ``s = 1`` it is
    ``(C + Q)^-1``).
    """

    if np.ndim(correlation_mm) == 2:
        return _local_posterior(data_precision, 0, area_mm2, tau2, correlation_mm, order, spectrum, gain)[0]
    values, vectors, scale = _whitened_eigen(data_precision, tau2)
    unit = _unit_symbol(area_mm2, correlation_mm, order)  # (bins, n)
    lam, weight = lattice_spectrum()
    seen = values[None] * (1.0 if gain is None else gain[:, :, None])  # (bins, n, k)
    # (C + u diag(1/tau2))^-1 = S V diag(1 / (values + u)) V^T S with S = diag(tau)
    denominator = seen + unit[:, :, None]
    if spectrum is None:
        inverse_sum = np.einsum("j,jnk->nk", weight, 1.0 / denominator)
    else:
        s = np.asarray(spectrum, np.float64)[:, None, None]
        inverse_sum = np.einsum("j,jnk->nk", weight, (s * seen + unit[:, :, None]) / denominator ** 2)
    covariance = np.einsum("nik,nk,njk->nij", vectors, inverse_sum, vectors)
    return covariance * scale[None, :, None] * scale[None, None, :]


def held_map_error_covariance(data_precision, held, area_mm2, tau2, correlation_mm, order=1, spectrum=None,
                              gain=None):
    """Per-texel covariance ``(n, k, k)`` of the error of the first ``k`` maps' posterior mode when
    the last ``held`` maps are not estimated but held at their prior mean.

    The fit renders at the face's thickness and oxygenation and the input index; the truth's
    differ within the face by Matérn fields of spread ``tau2[k:]``. Over the lattice spectrum
    (:func:`lattice_spectrum`) the error of the fitted maps' mode at frequency ``lambda`` is
    ``A^-1 (J_c^T e - Q_c c) + A^-1 C_ch dh`` with ``A = C_cc + Q_c``, so its covariance is
    :func:`posterior_covariance`'s sandwich on ``C_cc`` plus ``A^-1 C_ch Q_h^-1 C_hc A^-1``
    (``Q = u(lambda) diag(1 / tau^2)``), zone averaged. The joint posterior's chromophore
    block (the held maps marginalized, Schur complement) is smaller wherever the data could
    tell the held maps (the band shape tells the oxygenation): it is the uncertainty of an
    estimate that fits them, not of one that holds them.

    Parameters
    ----------
    data_precision : (n, k + held, k + held)
        The Gauss-Newton normal matrix per texel over the fitted and then the held maps.
    held : int
        How many trailing maps are held.
    area_mm2, tau2, correlation_mm, order, spectrum, gain :
        As :func:`posterior_covariance`; ``tau2`` has one entry per map, held ones included.
    """

    C = np.asarray(data_precision, np.float64)
    tau2 = np.asarray(tau2, np.float64)
    if np.ndim(correlation_mm) == 2:
        return _local_posterior(C, held, area_mm2, tau2, correlation_mm, order, spectrum, gain)[0]
    k = C.shape[-1] - int(held)
    covariance = posterior_covariance(C[:, :k, :k], area_mm2, tau2[:k], correlation_mm, order, spectrum, gain)
    if held <= 0:
        return covariance
    values, vectors, scale = _whitened_eigen(C[:, :k, :k], tau2[:k])
    # the held maps' data coupling in the fitted maps' whitened eigenbasis
    coupling = np.einsum("nik,i,nih,h->nkh", vectors, scale, C[:, :k, k:], np.sqrt(tau2[k:]))
    outer = np.einsum("nah,nbh->nab", coupling, coupling)
    unit = _unit_symbol(area_mm2, correlation_mm, order)
    _, weight = lattice_spectrum()
    factor = np.zeros_like(outer)
    for j in range(unit.shape[0]):  # one bin at a time: (n, k, k) memory, not (bins, n, k, k)
        u = unit[j][:, None]
        g = np.ones_like(u) if gain is None else gain[j][:, None]
        inverse = 1.0 / (g * values + u)
        # the held maps' coupling reaches the data through the blur as the fitted maps do
        factor += (weight[j] * g[:, :, None] ** 2 / u[:, :, None]) * inverse[:, :, None] * inverse[:, None, :]
    extra = np.einsum("nia,nab,njb->nij", vectors, outer * factor, vectors)
    return covariance + extra * scale[None, :, None] * scale[None, None, :]


def _local_posterior(data_precision, held, area_mm2, tau2, correlation_mm, order, spectrum, gain):
    """``(covariance (n, f, f), prior energy share (n, f))`` of :func:`held_map_error_covariance`
    and :func:`expected_prior_energy` for maps of their own correlation length and spread per
    texel (``correlation_mm`` (n, k), ``tau2`` (k,) or (n, k)), by a k x k solve per texel and
    frequency (the eigenbasis those functions share holds only for one symbol for every
    map); ``f = k - held``."""
    C = np.asarray(data_precision, np.float64)
    n, k, _ = C.shape
    f = k - int(held)
    tau2 = np.broadcast_to(np.asarray(tau2, np.float64), (n, k))
    area = np.asarray(area_mm2, np.float64)[:, None]
    l2 = np.asarray(correlation_mm, np.float64) ** 2
    lam, weight = lattice_spectrum()
    covariance = np.zeros((n, f, f))
    share = np.zeros((n, f))
    eye = np.eye(f)
    for j, value in enumerate(lam):  # one frequency at a time: (n, k, k) memory
        u = area * (1.0 + l2 * value / area) ** order
        g = 1.0 if gain is None else gain[j][:, None, None]
        prior = (u[:, :f] / tau2[:, :f])[:, :, None] * eye
        inverse = batched_spd_inverse(g * C[:, :f, :f] + prior)
        if spectrum is None:
            term = inverse
        else:
            term = inverse @ (spectrum[j] * g * C[:, :f, :f] + prior) @ inverse
        if held:
            coupling = g * C[:, :f, f:]
            held_variance = tau2[:, f:] / u[:, f:]
            term = term + inverse @ np.einsum("nah,nh,nbh->nab", coupling, held_variance, coupling) @ inverse
        covariance += weight[j] * term
        share += weight[j] * u[:, :f] * np.einsum("nii->ni", inverse)
    return covariance, share


def _unit_symbol(area_mm2, correlation_mm, order):
    """``u = area (1 + l^2 lambda / area)^order`` (bins, n) over the lattice spectrum's nodes."""
    lam, _ = lattice_spectrum()
    area = np.asarray(area_mm2, np.float64)[None, :]
    return area * (1.0 + float(correlation_mm) ** 2 * lam[:, None] / area) ** order


def _whitened_eigen(data_precision, tau2):
    """Eigenvalues (n, k) and vectors (n, k, k) of ``S C S``, ``S = diag(sqrt(tau2))``, and ``S``'s diagonal.

    With them ``(C + u diag(1 / tau2))^-1`` is ``S V diag(1 / (values + u)) V^T S``
    for every ``u`` at the cost of one symmetric eigendecomposition per texel."""

    tau2 = np.asarray(tau2, np.float64)
    if not np.all(np.isfinite(tau2) & (tau2 > 0)):
        raise ValueError("every map needs a finite prior spread (tau2 > 0)")
    scale = np.sqrt(tau2)
    C = np.asarray(data_precision, np.float64)
    values, vectors = np.linalg.eigh(C * scale[None, :, None] * scale[None, None, :])
    return np.maximum(values, 0.0), vectors, scale


def expected_prior_energy(data_precision, area_mm2, tau2, correlation_mm, order=1, gain=None):
    """Per texel and map ``(n, k)``: the posterior expectation of a deviation's share of
    ``d^T U d`` (``U`` the unit precision, ``Q = U / tau^2``) beyond its posterior mean's.

    The zone average of ``u(lambda) [(C + diag(u(lambda) / tau^2))^-1]_mm`` with
    ``u = area (1 + l^2 lambda / area)^order``: summed over texels, the trace
    ``tr(U Sigma)`` of the expectation-maximization update of ``tau^2``
    (:func:`updated_spread`). ``correlation_mm`` and ``gain`` as :func:`posterior_covariance`."""

    if np.ndim(correlation_mm) == 2:
        return _local_posterior(data_precision, 0, area_mm2, tau2, correlation_mm, order, None, gain)[1]
    values, vectors, scale = _whitened_eigen(data_precision, tau2)
    unit = _unit_symbol(area_mm2, correlation_mm, order)
    _, weight = lattice_spectrum()
    seen = values[None] * (1.0 if gain is None else gain[:, :, None])
    # u [S V diag(1 / (values + u)) V^T S]_mm = u tau2_m sum_k V_mk^2 / (values_k + u)
    share = np.einsum("j,jn,jnk->nk", weight, unit, 1.0 / (seen + unit[:, :, None]))
    return np.einsum("nmk,nk->nm", vectors ** 2, share) * scale[None, :] ** 2


def updated_spread(deviation, unit, expected_energy, tau2, std):
    """The expectation-maximization update of a map's spread: ``(tau2, std)``.

    ``tau2_new = (d^T U d + tr(U Sigma)) / n`` for the posterior mean's deviation
    ``d`` (n,) from the face mean, ``U`` the unit precision and ``tr(U Sigma)``
    the sum of :func:`expected_prior_energy` (Dempster, Laird and Rubin, J. R.
    Stat. Soc. B 39, 1977: the M step of a Gaussian's scale). Where the data do
    not tell the map, the posterior is the prior, the update returns about the
    spread it was given; where they do, it moves to the spread the data show."""

    n = len(deviation)
    new_tau2 = (float(deviation @ (unit @ deviation)) + float(np.sum(expected_energy))) / max(n, 1)
    return new_tau2, float(std) * np.sqrt(new_tau2 / float(tau2))


def mean_mode_covariance(data_precision, area_mm2, tau2, mean_variance):
    """Per-texel covariance ``(n, k, k)`` that the face means' uncertainty adds.

    The means ``mu`` (k,) have a Gaussian hyperprior of variance
    ``mean_variance`` (k,; 0 for a map whose mean is fixed). Through the
    constant spatial mode (prior symbol ``D_i = area_i / tau^2``), a change of
    ``mu`` moves texel ``i`` by ``M_i = (C_i + D_i)^-1 D_i``; ``mu``'s
    posterior precision is ``S = sum_i (D_i - D_i M_i) + diag(1 / mean_variance)``,
    and the texel's covariance gains ``M_i S^-1 M_i^T``. Returns it and ``S^-1``.
    """

    C = np.asarray(data_precision, np.float64)
    n, k, _ = C.shape
    mean_variance = np.asarray(mean_variance, np.float64)
    free = mean_variance > 0
    if not free.any():
        return np.zeros_like(C), np.zeros((k, k))
    D = (np.asarray(area_mm2, np.float64)[:, None] / np.asarray(tau2, np.float64)[None, :])
    D[:, ~free] = 0.0
    Dm = D[:, :, None] * np.eye(k)
    M = np.linalg.solve(C + Dm + 1e-30 * np.eye(k), Dm)
    S = np.sum(Dm - Dm @ M, axis=0)
    S[np.ix_(~free, ~free)] = np.eye(int((~free).sum()))
    S[np.ix_(free, ~free)] = 0.0
    S[np.ix_(~free, free)] = 0.0
    S[free, free] += 1.0 / mean_variance[free]
    covariance = np.linalg.inv(S)
    covariance[~free, :] = 0.0
    covariance[:, ~free] = 0.0
    return M @ covariance @ np.swapaxes(M, 1, 2), covariance


FFT_THREADED_TEXELS = 512 * 512
"""From this many texels :class:`FourierPreconditioner`'s FFTs run on every core (scipy's
``workers=-1``), below it on one: four maps' forward and inverse FFT on two idle cores took
0.80 / 1.06 ms at 128^2, 3.26 / 3.61 ms at 256^2 and 16.7 / 11.9 ms at 512^2 (one / every
core; 2026-12-07, bench/RESULTS.md), and threads a process starts beside other busy ones
(two test workers, Dask's frames) only wait for a core."""


class FourierPreconditioner:
    """``P^-1`` for the Gauss-Newton system ``C + Q``: its exact inverse for constant data.

    ``P`` replaces each texel's data block by their mean ``C_mean`` (k x k)
    and the prior by the same Matérn operator on the whole periodic texture
    grid (texels of the median area), so it is diagonal in the 2-D discrete
    Fourier basis: per frequency, the k x k block ``C_mean + diag(q(omega) /
    tau^2)`` with ``q`` the lattice symbol of :func:`posterior_covariance`.
    Conjugate gradients then iterate only on how much the data vary over the
    face; block-Jacobi would iterate on the prior's condition number, which
    grows as ``(l / h)^(2 order)``.

    Parameters
    ----------
    shape : (T, T)
    index : (n,) int
        Flat grid index of each unknown (the prior's surface texels).
    area_mm2 : float
    tau2 : (k,) float (``inf``: a map without a prior)
    mean_block : (k, k)
    correlation_mm : float
    order : {1, 2}
    """

    def __init__(self, shape, index, area_mm2, tau2, mean_block, correlation_mm, order=1):
        self.shape = tuple(shape)
        self.index = np.asarray(index)
        rows, cols = self.shape
        fu = np.fft.fftfreq(rows)[:, None]
        fv = np.fft.rfftfreq(cols)[None, :]
        lam = 4.0 * (np.sin(np.pi * fu) ** 2 + np.sin(np.pi * fv) ** 2)
        symbol = area_mm2 * (1.0 + float(correlation_mm) ** 2 * lam / area_mm2) ** order
        inverse_tau2 = np.where(np.isfinite(tau2), 1.0 / np.asarray(tau2, np.float64), 0.0)
        k = len(inverse_tau2)
        block = (np.asarray(mean_block, np.float64)[None, None]
                 + (symbol[..., None] * inverse_tau2)[..., None] * np.eye(k) + 1e-30 * np.eye(k))
        self.inverse = np.linalg.inv(block)

    def __call__(self, x):
        """``P^-1 x`` for ``x`` (n, k) over the unknowns."""
        n, k = x.shape
        grid = np.zeros((self.shape[0] * self.shape[1], k))
        grid[self.index] = x
        workers = -1 if grid.shape[0] >= FFT_THREADED_TEXELS else 1
        spectrum = fft.rfft2(grid.reshape(*self.shape, k), axes=(0, 1), workers=workers)
        spectrum = np.matmul(self.inverse, spectrum[..., None])[..., 0]
        out = fft.irfft2(spectrum, s=self.shape, axes=(0, 1), workers=workers).reshape(-1, k)
        return out[self.index]


def known_mean_covariance(data_precision, area_mm2, tau2, mean_variance):
    """Per-texel covariance ``(n, k, k)`` that face means estimated elsewhere add.

    A mean known to variance ``v`` (k,) moves texel ``i`` by ``M_i = (C_i + D_i)^-1 D_i``
    per unit (:func:`mean_mode_covariance`), so it adds ``M_i diag(v) M_i^T``."""

    C = np.asarray(data_precision, np.float64)
    k = C.shape[1]
    D = np.asarray(area_mm2, np.float64)[:, None] / np.asarray(tau2, np.float64)[None, :]
    Dm = D[:, :, None] * np.eye(k)
    M = np.linalg.solve(C + Dm + 1e-30 * np.eye(k), Dm)
    return np.einsum("nik,k,njk->nij", M, np.asarray(mean_variance, np.float64), M)
