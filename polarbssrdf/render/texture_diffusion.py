"""Texture-space blurring with sums of Gaussians (supplement eq. 43-46, d'Eon et al. 2007).

A radially symmetric diffusion profile written as a normalized sum of
Gaussians ``G(r) = sum_j w_j G(v_j, r)`` (``sum_j w_j = 1``, variances in mm^2,
``G(v, r) = exp(-r^2 / 2v) / (2 pi v)``) is applied to a map in texture space
as separable 1-D convolutions along ``u`` and ``v``. Texels are not square
nor equal in size across a face, so each output texel uses its own extent in
mm (a "stretch map", from :class:`polarbssrdf.geometry.TexelAtlas`), and
each 1-D kernel is renormalized over the valid texels it covers: the blur
conserves energy per texel and does not leak into or out of the empty parts
of the atlas. Gaussians narrower than half a texel are the identity at this
resolution.

A whole sum of Gaussians is two fused Dr.Jit kernels: the ``u`` passes of
every Gaussian in one (each Gaussian's taps a symbolic loop over the offsets
whose bound, its half width, is a kernel input, so the kernel is the same
whatever the widths), the ``v`` passes and the weighted sum in the other; on the
backend of a Dr.Jit input or on the LLVM backend for NumPy input. Each
Gaussian keeps its own normalization per pass, precomputed once per atlas
and variance (:class:`BlurGeometry`). With an AD-enabled Dr.Jit input the
blur is one custom AD operation (:class:`_SumOfGaussiansBlur`): the blur is
linear in the map, so its reverse derivative is the adjoint blur (three
fused kernels), not an AD graph of every tap (which is about 100x slower).
Gaussians narrower than the texels on both axes are merged into one identity
term.
"""

from __future__ import annotations

import numpy as np

from polarbssrdf._arrays import to_jit

MAX_TAPS_PER_SIDE = 1024
"""A safety cap only: +-4 sigma at the smallest texel is always covered below it (a
2048^2 face's smallest texels are about 0.07 mm, the widest Gaussian of a skin
profile with a weight above ``negligible_weight`` about 1 mm: 60 taps)."""
SIGMAS_COVERED = 4.0  # +-4 sigma keeps 99.99% of the mass and 99.9% of the variance
IDENTITY_SIGMAS = 5.3  # a texel wider than this many sigma: neighbours weigh < 1e-6, the pass is skipped



def _backend_module(texture):
    """The Dr.Jit backend module to compute in, and whether the input was NumPy."""
    import drjit as dr

    if isinstance(texture, np.ndarray):
        return dr.llvm, True
    return sys_module(texture), False


def half_width_texels(variance_mm2, texel_mm, valid_mask, max_taps=MAX_TAPS_PER_SIDE):
    """Taps on each side needed to cover +-4 sigma at the smallest valid texel."""
    smallest = texel_mm[valid_mask].min() if np.any(valid_mask) else 1.0
    return int(min(np.ceil(SIGMAS_COVERED * np.sqrt(variance_mm2) / max(smallest, 1e-9)), max_taps))


class BlurGeometry:
    """What the passes over one atlas share, on one Dr.Jit backend.

    Texel sizes and the surface mask as flat arrays, and per Gaussian
    variance its 1-D passes: ``(axis, half width, 1 / W)`` with ``W_i`` the
    summed weight of the valid taps of texel ``i`` (0 where there are none),
    computed once. :func:`blur_geometry` keeps the last few.
    """

    def __init__(self, texel_size_mm, valid_mask, module):
        self.module = module
        self.shape = tuple(valid_mask.shape)
        self.valid_mask = np.asarray(valid_mask, bool)
        self.texel_size_mm = np.asarray(texel_size_mm)
        Float = module.Float
        self.valid = to_jit(Float, self.valid_mask.ravel(), np.float32)
        self.texel_mm = {1: self.texel_size_mm[..., 0], 0: self.texel_size_mm[..., 1]}
        self.texel_mm_jit = {axis: to_jit(Float, np.ravel(sizes), np.float32)
                             for axis, sizes in self.texel_mm.items()}
        self._smallest = {axis: (float(sizes[self.valid_mask].min()) if self.valid_mask.any()
                                 else 1.0) for axis, sizes in self.texel_mm.items()}
        self._passes = {}

    def passes(self, variance_mm2):
        """``[(axis, half_width, inverse weight sum)]`` of the non-trivial passes (u, then v)."""
        key = float(variance_mm2)
        if key not in self._passes:
            import drjit as dr

            plan = []
            for axis in (1, 0):  # along u (columns), then v (rows)
                half_width = half_width_texels(key, self.texel_mm[axis], self.valid_mask)
                # the nearest tap weighs < 1e-6 of the centre at every texel: the identity
                if half_width > 0 and self._smallest[axis] ** 2 < IDENTITY_SIGMAS ** 2 * key:
                    weight_sum = _tap_sums([None], [key], [half_width], axis, self)[0]
                    inverse = dr.select(weight_sum > 0, dr.rcp(weight_sum), 0.0)
                    dr.eval(inverse)
                    plan.append((axis, half_width, inverse))
            self._passes[key] = plan
        return self._passes[key]

    def is_identity(self, variance_mm2):
        return not self.passes(variance_mm2)


_GEOMETRIES = []
_GEOMETRY_CACHE_SIZE = 4


def blur_geometry(texel_size_mm, valid_mask, module):
    """The :class:`BlurGeometry` of these arrays (the same objects reuse one, LRU of 4)."""
    for entry in _GEOMETRIES:
        if (entry.texel_size_mm is texel_size_mm and entry.valid_mask_source is valid_mask
                and entry.module is module):
            _GEOMETRIES.remove(entry)
            _GEOMETRIES.insert(0, entry)
            return entry
    entry = BlurGeometry(texel_size_mm, valid_mask, module)
    # the source objects are kept, so their ids cannot be reused while cached
    entry.texel_size_mm, entry.valid_mask_source = texel_size_mm, valid_mask
    _GEOMETRIES.insert(0, entry)
    del _GEOMETRIES[_GEOMETRY_CACHE_SIZE:]
    return entry


class _Lines:
    """Where each texel sits on its line along ``axis``; :meth:`neighbour` steps along it."""

    def __init__(self, axis, geometry):
        import drjit as dr

        module = geometry.module
        UInt32, Int32 = module.UInt32, module.Int32
        rows, cols = geometry.shape
        # the texture's size enters as kernel inputs, not literals: one compiled blur serves
        # every texture size (a literal compiled the blur's 40-70 kernels anew per size)
        sizes = geometry.__dict__.get("_opaque_sizes")
        if sizes is None:
            sizes = geometry._opaque_sizes = (dr.opaque(UInt32, cols), dr.opaque(Int32, rows),
                                              dr.opaque(Int32, cols))
        self.cols, rows_i, cols_i = sizes
        self.axis, self.UInt32 = axis, UInt32
        index = dr.arange(UInt32, rows * cols)
        self.row, self.col = index // self.cols, index % self.cols
        self.position = Int32(self.col if axis == 1 else self.row)
        self.length = cols_i if axis == 1 else rows_i

    def neighbour(self, step):
        """(inside, flat index) of the texel ``step`` (an Int32 array) away along the axis."""
        import drjit as dr

        target = self.position + step
        inside = (target >= 0) & (target < self.length)
        clamped = self.UInt32(dr.clip(target, 0, self.length - 1))
        index = self.row * self.cols + clamped if self.axis == 1 else clamped * self.cols + self.col
        return inside, index


def _tap_sums(sources, variances, half_widths, axis, geometry, adjoint=False):
    """Per Gaussian ``j``: ``sum_o g_j(o, t) source_j[i + o]`` along ``axis`` (one kernel's worth).

    Forward (``adjoint=False``): ``t`` is the output texel's size, the
    sources are valid-masked (a ``None`` source sums the weights of the valid
    taps: the normalization). Adjoint: ``t`` is the size of the texel the
    tap comes from (``i - o``), as the transpose of the forward pass needs.

    Each Gaussian's offsets are a symbolic loop (``dr.while_loop``) whose bound, its half
    width, is a kernel input: one small kernel per number of Gaussians, axis and direction,
    whatever the widths. Unrolled, a pass of a skin profile's Gaussians was one kernel of
    5,000-8,000 operations that LLVM took several seconds to compile, a new one for every set
    of widths (bench/RESULTS.md, 2026-12-08). A loop per Gaussian, not one over the widest
    with the narrower masked: a profile's widths differ tenfold, and the masked taps made a
    512^2 biophysical loss twice as slow.
    """
    import drjit as dr

    module = geometry.module
    Float, Int32 = module.Float, module.Int32
    texel_mm = geometry.texel_mm_jit[axis]
    lines = _Lines(axis, geometry)
    totals = []
    for source, variance, half_width in zip(sources, variances, half_widths):
        values = geometry.valid if source is None else source
        # the Gaussians change with the skin and the band: kernel inputs, not literals
        scale, width = dr.opaque(Float, -0.5 / variance), dr.opaque(Int32, half_width)

        def taps(offset, *state):
            return offset <= width

        def step(offset, total, *recursion):
            if not adjoint:  # q^(o^2) = q^((o-1)^2) q^(2o - 1)
                weight, ratio = recursion
                weight, ratio = weight * ratio, ratio * q2
            for sign in (1, -1):
                inside, neighbour = lines.neighbour(offset * (-sign if adjoint else sign))
                if adjoint:
                    distance2 = Float(offset * offset) * dr.square(dr.gather(Float, texel_mm, neighbour))
                    tap = dr.exp(distance2 * scale)
                else:
                    tap = weight
                total = total + tap * dr.gather(Float, values, neighbour, inside)
            return (offset + 1, total) + (() if adjoint else (weight, ratio))

        recursion = ()
        if not adjoint:
            # g(o, t) = q^(o^2) with q = exp(-t^2 / 2v): two products per tap instead of an exp
            q = dr.exp(dr.square(texel_mm) * scale)
            recursion, q2 = (Float(1.0), q), dr.square(q)
        # offset 0 weighs 1 and is always inside
        state = dr.while_loop((Int32(1), Float(values)) + recursion, taps, step)
        totals.append(state[1])
    return totals


def _stage(axis, gaussian_passes):
    """The pass of each Gaussian along ``axis``: ``(half_width, inverse)`` or None."""
    out = []
    for passes in gaussian_passes:
        found = [(h, inverse) for a, h, inverse in passes if a == axis]
        out.append(found[0] if found else None)
    return out


def _prepare_terms(values, terms, geometry):
    """What the forward blur and its adjoint share: the valid-masked input (evaluated), the
    Gaussian terms, the identity weight, and each Gaussian's pass along u and along v."""
    import drjit as dr

    masked = values * geometry.valid
    dr.eval(masked)
    gaussians = [(w, v) for w, v in terms if v is not None]
    identity = sum(w for w, v in terms if v is None)
    passes = [geometry.passes(v) for _, v in gaussians]
    return masked, gaussians, identity, _stage(1, passes), _stage(0, passes)


def _sum_of_gaussians(values, terms, geometry):
    """Forward ``sum_j w_j V_j U_j x`` (+ identity term) on a flat array: two fused kernels."""
    import drjit as dr

    valid = geometry.valid
    masked, gaussians, identity, along_u, along_v = _prepare_terms(values, terms, geometry)
    # u passes of every Gaussian: one kernel
    active = [j for j, p in enumerate(along_u) if p is not None]
    stage_u = [masked] * len(gaussians)
    if active:
        sums = _tap_sums([masked] * len(active), [gaussians[j][1] for j in active],
                         [along_u[j][0] for j in active], 1, geometry)
        for j, total in zip(active, sums):
            stage_u[j] = total * along_u[j][1] * valid
        dr.eval(*[stage_u[j] for j in active])
    # v passes and the weighted sum: one kernel
    # the weights are fitted per skin and band: kernel inputs, not literals
    result = masked * dr.opaque(type(values), identity) if identity else dr.zeros(type(values), len(values))
    active = [j for j, p in enumerate(along_v) if p is not None]
    sums = _tap_sums([stage_u[j] for j in active], [gaussians[j][1] for j in active],
                     [along_v[j][0] for j in active], 0, geometry) if active else []
    blurred = dict(zip(active, sums))
    for j, (weight, _) in enumerate(gaussians):
        term = blurred[j] * along_v[j][1] if j in blurred else stage_u[j]
        result = result + term * dr.opaque(type(values), weight)
    result = result * valid
    dr.eval(result)
    return result


def _sum_of_gaussians_adjoint(grad, terms, geometry):
    """The transpose of :func:`_sum_of_gaussians` applied to ``grad``: three fused kernels.

    Forward pass along an axis: ``y_i = v_i sum_o g(o, t_i) v_(i+o) x_(i+o) / W_i``;
    its transpose: ``xbar_j = v_j sum_o g(o, t_(j-o)) s_(j-o)``, ``s_i = v_i ybar_i / W_i``.
    """
    import drjit as dr

    valid = geometry.valid
    masked, gaussians, identity, along_u, along_v = _prepare_terms(grad, terms, geometry)
    # transpose of the v passes
    scaled = [masked * dr.opaque(type(grad), w) * (along_v[j][1] if along_v[j] is not None else 1.0)
              for j, (w, _) in enumerate(gaussians)]
    active = [j for j, p in enumerate(along_v) if p is not None]
    dr.eval(*[scaled[j] for j in active])
    stage_v = list(scaled)
    if active:
        sums = _tap_sums([scaled[j] for j in active], [gaussians[j][1] for j in active],
                         [along_v[j][0] for j in active], 0, geometry, adjoint=True)
        for j, total in zip(active, sums):
            stage_v[j] = total * valid
    # scale for the transpose of the u passes, in the same kernel
    for j in range(len(gaussians)):
        if along_u[j] is not None:
            stage_v[j] = stage_v[j] * along_u[j][1]
    if stage_v:
        dr.eval(*stage_v)
    result = masked * dr.opaque(type(grad), identity) if identity else dr.zeros(type(grad), len(grad))
    active = [j for j, p in enumerate(along_u) if p is not None]
    sums = _tap_sums([stage_v[j] for j in active], [gaussians[j][1] for j in active],
                     [along_u[j][0] for j in active], 1, geometry, adjoint=True) if active else []
    blurred = dict(zip(active, sums))
    for j in range(len(gaussians)):
        result = result + (blurred[j] if j in blurred else stage_v[j])
    result = result * valid
    dr.eval(result)
    return result


def blur_separable(texture, variance_mm2, texel_size_mm, valid_mask):
    """Blur a (T, T) map with one Gaussian of variance ``variance_mm2`` (mm^2), separably."""
    module, from_numpy = _backend_module(texture)
    geometry = blur_geometry(texel_size_mm, valid_mask, module)
    values = to_jit(module.Float, np.ravel(texture), np.float32) if from_numpy else texture.array
    if geometry.is_identity(variance_mm2):
        values = values * geometry.valid
    else:
        values = _sum_of_gaussians(values, [(1.0, float(variance_mm2))], geometry)
    if from_numpy:
        return np.array(values, dtype=np.float32).reshape(geometry.shape)
    return type(texture)(values, geometry.shape)


class _SumOfGaussiansBlur:
    """Placeholder replaced by the Dr.Jit custom op class (defined lazily: drjit import)."""


def _custom_blur_class():
    import drjit as dr

    global _SumOfGaussiansBlur
    if isinstance(_SumOfGaussiansBlur, type) and issubclass(_SumOfGaussiansBlur, dr.CustomOp):
        return _SumOfGaussiansBlur

    class SumOfGaussiansBlur(dr.CustomOp):
        """``sum_j w_j G(v_j) * x`` as one AD node: forward blur, reverse = adjoint blur."""

        def eval(self, values, terms, geometry):
            self.terms, self.geometry = terms, geometry
            return _sum_of_gaussians(values, terms, geometry)

        def backward(self):
            self.set_grad_in("values", _sum_of_gaussians_adjoint(self.grad_out(), self.terms,
                                                                 self.geometry))

        def forward(self):
            raise NotImplementedError("the sum-of-Gaussians blur supports reverse-mode AD only")

        def name(self):
            return "SumOfGaussiansBlur"

    _SumOfGaussiansBlur = SumOfGaussiansBlur
    return SumOfGaussiansBlur


def sys_module(array):
    import sys

    return sys.modules[type(array).__module__]


def blur_sum_of_gaussians(texture, weights, variances_mm2, texel_size_mm, valid_mask,
                          negligible_weight=1e-4):
    """``sum_j w_j (G(v_j) * texture)`` in texture space; eq. 44-45.

    Parameters
    ----------
    texture : (T, T) array or TensorXf
        The map to blur (e.g. transmitted irradiance times albedo).
    weights : sequence of float
        Normalized SoG weights ``w_j`` (they should sum to 1 to conserve energy).
    variances_mm2 : sequence of float
        Gaussian variances ``v_j``, mm^2.
    texel_size_mm : (T, T, 2) array
        Texel extent along ``u`` and ``v``, mm (``TexelAtlas.texel_size_mm``).
    valid_mask : (T, T) bool
        Texels on the surface.
    negligible_weight : float
        Gaussians whose share of the total weight is below this are dropped
        and the others rescaled to the same total (a fitted ladder carries
        many weights of 1e-6 whose wide kernels would dominate the cost).
    """
    weights = np.asarray(weights, dtype=np.float64)
    variances = np.asarray(variances_mm2, dtype=np.float64)
    if weights.shape != variances.shape:
        raise ValueError(f"{len(weights)} SoG weights for {len(variances)} variances")
    if np.any(variances <= 0) or not np.all(np.isfinite(variances)):
        raise ValueError("SoG variances must be positive and finite")
    if texture.shape[:2] != valid_mask.shape or texel_size_mm.shape[:2] != valid_mask.shape:
        raise ValueError(f"map {texture.shape}, texel sizes {texel_size_mm.shape} and mask "
                         f"{valid_mask.shape} must share their first two dimensions")
    total = weights.sum()
    kept = np.abs(weights) >= negligible_weight * np.abs(weights).sum()
    if np.any(kept) and weights[kept].sum() != 0:
        weights = np.where(kept, weights * total / weights[kept].sum(), 0.0)
    module, from_numpy = _backend_module(texture)
    geometry = blur_geometry(texel_size_mm, valid_mask, module)
    # Gaussians that are the identity on both axes: one term
    terms, identity = [], 0.0
    for weight, variance in zip(weights, variances):
        if weight == 0:
            continue
        if geometry.is_identity(variance):
            identity += float(weight)
        else:
            terms.append((float(weight), float(variance)))
    if identity != 0.0:
        terms.insert(0, (identity, None))
    if not terms:
        return texture * 0.0
    shape = geometry.shape
    if from_numpy:
        values = to_jit(module.Float, np.ravel(texture), np.float32)
        return np.array(_sum_of_gaussians(values, terms, geometry),
                        dtype=np.float32).reshape(shape)
    import drjit as dr

    if dr.grad_enabled(texture):
        values = dr.custom(_custom_blur_class(), texture.array, terms, geometry)
    else:
        values = _sum_of_gaussians(texture.array, terms, geometry)
    return type(texture)(values, shape)
