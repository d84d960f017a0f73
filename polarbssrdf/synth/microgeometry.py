"""Wrinkles and pores in the truth's displacement map (issue 33, item 1).

A face's relief is more than one smooth field: furrows run across the forehead,
fan out from the eye corners (crow's feet) and from the nose to the mouth
(nasolabial folds), and pores pit the cheeks and nose. :func:`relief_depth` adds both
to the displacement map synth draws (:func:`~polarbssrdf.synth.truth.truth_maps`), as
depths in mm below the surface.

**Shapes.** A wrinkle is a furrow of Gaussian cross-section along a path on the
surface: depth ``d`` (mm) at its centre line, full width at half depth ``w`` (mm),
tapered to 0 at both ends as ``sin(pi t)`` of the arc-length fraction ``t``. A pore
is a pit of Gaussian profile, depth ``d`` and full width at half depth ``w``,
centred at surface points drawn uniformly by area at a density per cm^2.

**What a texel holds.** A displacement map stores one height per texel: the mean
of the surface over it. A Gaussian of standard deviation ``s`` averaged over a
texel of size ``a`` is, to a close approximation, a Gaussian of variance
``s^2 + a^2 / 12`` (the texel's box has variance ``a^2 / 12``) with the same
volume, so a furrow's depth becomes ``d s / s_eff`` and a pit's ``d s^2 / s_eff^2``.
A feature narrower than a texel therefore survives as a shallower, texel-wide one;
:func:`unresolved_features` says which are below the texel size, and synth prints
it.

**Defaults** (:data:`DEFAULT_WRINKLE`, :data:`DEFAULT_PORES`, and the face's paths
in :func:`face_wrinkle_paths`): replica and optical 3D profilometry of facial skin
measures eye-corner furrows whose depth grows from the forties and plateaus at
sixty (Akazaki et al., Br. J. Dermatol. 147:689, 2002) and finds the furrows of the
eye corners, mouth angles, glabella, nasolabial groove and forehead deepen with age
in that order (Takema et al., Skin Res. Technol. 3:95, 1997); visible cheek pores
were counted above a 0.25 mm detection threshold on 2,585 women (Flament et al.,
Clin. Cosmet. Investig. Dermatol. 8:85, 2015). The defaults are of that scale, a
tenth of a millimetre deep, pores at the visible threshold; they are settings of a
synthetic face, not measurements of one.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from polarbssrdf.geometry.displaced import filled_off_chart
from polarbssrdf.io.jsonfile import check_object_keys

FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))
"""Full width at half maximum of a Gaussian, in standard deviations (2.355)."""

DEFAULT_WRINKLE = {"depth_mm": 0.15, "width_mm": 0.8}
"""Depth and full width at half depth of the face's default furrows, mm."""

DEFAULT_PORES = {"density_per_cm2": 40.0, "diameter_mm": 0.3, "depth_mm": 0.08}
"""Pores per cm^2 of surface, and each pit's full width at half depth and depth, mm."""

WRINKLE_KEYS = {
    "path_uv": "the furrow's centre line: a list of at least two [u, v] texture coordinates in [0, 1]",
    "depth_mm": "depth at the centre line, mm (> 0)",
    "width_mm": "full width at half depth, mm (> 0)",
    "name": "an optional label for the record",
}
"""Keys of one wrinkle (``TruthSettings.wrinkles``), as docs/synth.md lists them."""

PORE_KEYS = {
    "density_per_cm2": "pits per cm^2 of surface (>= 0; 0: no pores)",
    "diameter_mm": "full width at half depth of each pit, mm (> 0)",
    "depth_mm": "depth of each pit, mm (>= 0)",
}
"""Keys of ``TruthSettings.pores``."""

SAMPLES_PER_SIGMA = 4
"""A furrow's centre line is sampled this many times per standard deviation of its
(texel-averaged) cross-section, so the distance to the nearest sample is the
distance to the line within a few percent of the width."""

REACH_SIGMAS = 4.0
"""Texels farther than this many standard deviations from a feature get nothing from it."""

# Landmarks of the canonical (MediaPipe) face mesh the default paths follow
# (indices of its first 468 vertices). Brow line, outer to outer through the glabella:
BROW_LANDMARKS = (70, 63, 105, 66, 107, 9, 336, 296, 334, 293, 300)
# The upper forehead, outer to outer through the hairline's centre:
FOREHEAD_TOP_LANDMARKS = (103, 67, 109, 10, 338, 297, 332)
# Eye corners (outer, inner) of the subject's right and left eye:
EYE_CORNERS = ((33, 133), (263, 362))
# Nose wing and mouth corner of each side:
NASOLABIAL = ((129, 61), (358, 291))


def texel_sigma_mm(width_mm, texel_mm):
    """``(s, s_eff)``: a feature's standard deviation from its full width at half depth, and
    that of its average over a texel of ``texel_mm`` (module docstring), mm."""
    sigma = float(width_mm) / FWHM_PER_SIGMA
    return sigma, float(np.sqrt(sigma ** 2 + float(texel_mm) ** 2 / 12.0))


def _resampled(points, count):
    """``count`` points evenly spaced by arc length along the polyline ``points`` (n, k)."""
    points = np.asarray(points, np.float64)
    lengths = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    targets = np.linspace(0.0, lengths[-1], count)
    return np.stack([np.interp(targets, lengths, points[:, k]) for k in range(points.shape[1])], axis=1)


def face_wrinkle_paths(mesh, depth_mm=DEFAULT_WRINKLE["depth_mm"], width_mm=DEFAULT_WRINKLE["width_mm"]):
    """The face's default furrows as wrinkle dicts (Mitsuba ``uv``, as ``centers_uv``):
    three forehead lines between the brows and the upper forehead, three crow's feet
    fanning from each eye's outer corner, a nasolabial fold on each side.

    ``mesh``: the canonical face (its first 468 vertices are the landmarks), in mm."""
    uv = np.stack([mesh.uvs[:, 0], 1.0 - mesh.uvs[:, 1]], axis=1)  # OBJ v up -> Mitsuba v
    # mm per unit of uv, from the mesh's own edges (the layout is close to isometric on the face)
    edges = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]])
    scale = float(np.median(np.linalg.norm(np.diff(mesh.vertices[edges], axis=1)[:, 0], axis=1)
                            / np.maximum(np.linalg.norm(np.diff(uv[edges], axis=1)[:, 0], axis=1), 1e-12)))
    mm = 1.0 / scale  # uv per mm
    wrinkles = []
    brow = _resampled(uv[list(BROW_LANDMARKS)], 24)
    top = _resampled(uv[list(FOREHEAD_TOP_LANDMARKS)], 24)
    for k, fraction in enumerate((0.3, 0.5, 0.7)):
        line = brow + fraction * (top - brow)
        wrinkles.append({"path_uv": line[3:-3].tolist(), "name": f"forehead {k + 1}"})
    for side, (outer, inner) in zip(("right", "left"), EYE_CORNERS):
        along = uv[outer] - uv[inner]
        along /= np.linalg.norm(along)
        start = uv[outer] + 3.0 * mm * along
        for k, degrees in enumerate((-30.0, 0.0, 30.0)):
            turn = np.radians(degrees)
            direction = np.array([np.cos(turn) * along[0] - np.sin(turn) * along[1],
                                  np.sin(turn) * along[0] + np.cos(turn) * along[1]])
            wrinkles.append({"path_uv": [start.tolist(), (start + 12.0 * mm * direction).tolist()],
                             "name": f"crow's feet {side} {k + 1}"})
    centre_u = float(uv[list(FOREHEAD_TOP_LANDMARKS)][:, 0].mean())
    for side, (wing, mouth) in zip(("right", "left"), NASOLABIAL):
        outward = np.array([np.sign(uv[wing][0] - centre_u), 0.0])
        down = np.array([0.0, 1.0])
        start = uv[wing] + 2.0 * mm * outward
        corner = uv[mouth] + 5.0 * mm * outward
        middle = 0.5 * (start + corner) + 2.5 * mm * outward
        wrinkles.append({"path_uv": [start.tolist(), middle.tolist(), corner.tolist(),
                                     (corner + 8.0 * mm * down + 1.0 * mm * outward).tolist()],
                         "name": f"nasolabial {side}"})
    for wrinkle in wrinkles:
        wrinkle.update(depth_mm=float(depth_mm), width_mm=float(width_mm))
    return wrinkles


def _surface_points_at_uv(atlas, uv):
    """(n, 3) surface points (mm) at Mitsuba ``uv`` (n, 2): the atlas' points interpolated
    bilinearly (texels off the charts take their nearest valid texel's point first), so a
    path drawn through them is as smooth as its ``uv`` and does not step from texel to texel."""
    valid = np.asarray(atlas.valid, bool)
    T = valid.shape[0]
    position = filled_off_chart(atlas.position, valid)
    uv = np.asarray(uv, np.float64)
    coordinates = [uv[:, 1] * T - 0.5, uv[:, 0] * T - 0.5]  # rows follow v (polarbssrdf.geometry)
    return np.stack([ndimage.map_coordinates(position[..., k], coordinates, order=1, mode="nearest")
                     for k in range(3)], axis=1)


def wrinkle_depth(atlas, wrinkle, texel_mm):
    """(T, T) depth (mm, >= 0) one wrinkle carves into the texels (module docstring)."""
    sigma, sigma_eff = texel_sigma_mm(wrinkle["width_mm"], texel_mm)
    path = _surface_points_at_uv(atlas, _resampled(wrinkle["path_uv"], 256))
    length = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    count = max(2, int(np.ceil(length / sigma_eff * SAMPLES_PER_SIGMA)) + 1)
    samples = _resampled(path, count)
    fraction = np.linspace(0.0, 1.0, count)
    valid = np.asarray(atlas.valid, bool)
    points = atlas.position[valid].astype(np.float64)
    distance, nearest = cKDTree(samples).query(points, distance_upper_bound=REACH_SIGMAS * sigma_eff)
    near = np.isfinite(distance)
    depth = np.zeros(points.shape[0])
    depth[near] = (wrinkle["depth_mm"] * sigma / sigma_eff * np.sin(np.pi * fraction[nearest[near]])
                   * np.exp(-0.5 * (distance[near] / sigma_eff) ** 2))
    out = np.zeros(valid.shape)
    out[valid] = depth
    return out


def pore_depth(atlas, pores, texel_mm, rng):
    """(T, T) depth (mm, >= 0) of pores at ``pores["density_per_cm2"]``, centres drawn
    from ``rng`` uniformly by area (module docstring); overlapping pits add."""
    valid = np.asarray(atlas.valid, bool)
    area_mm2 = np.prod(atlas.texel_size_mm[valid].astype(np.float64), axis=-1)
    count = rng.poisson(pores["density_per_cm2"] * area_mm2.sum() / 100.0)
    out = np.zeros(valid.shape)
    if count == 0 or pores["depth_mm"] <= 0:
        return out
    points = atlas.position[valid].astype(np.float64)
    picks = rng.choice(points.shape[0], size=count, p=area_mm2 / area_mm2.sum())
    # a centre anywhere within its texel, not at the texel's centre
    sizes = atlas.texel_size_mm[valid][picks].astype(np.float64)
    tangent_u = atlas.dp_du[valid][picks].astype(np.float64)
    tangent_v = atlas.dp_dv[valid][picks].astype(np.float64)
    tangent_u /= np.maximum(np.linalg.norm(tangent_u, axis=1, keepdims=True), 1e-12)
    tangent_v /= np.maximum(np.linalg.norm(tangent_v, axis=1, keepdims=True), 1e-12)
    jitter = rng.uniform(-0.5, 0.5, size=(count, 2)) * sizes
    centres = points[picks] + jitter[:, :1] * tangent_u + jitter[:, 1:] * tangent_v
    sigma, sigma_eff = texel_sigma_mm(pores["diameter_mm"], texel_mm)
    depth = np.zeros(points.shape[0])
    for centre, texels in zip(centres, cKDTree(points).query_ball_point(centres, REACH_SIGMAS * sigma_eff)):
        if texels:
            texels = np.asarray(texels)
            squared = np.sum((points[texels] - centre) ** 2, axis=1)
            depth[texels] += pores["depth_mm"] * (sigma / sigma_eff) ** 2 * np.exp(-0.5 * squared / sigma_eff ** 2)
    out[valid] = depth
    return out


def unresolved_features(wrinkles, pores, texel_mm):
    """Sentences naming the features narrower than a texel (stored as their texel average)."""
    notes = []
    narrow = [w for w in wrinkles if w["width_mm"] < texel_mm]
    if narrow:
        kept = [texel_sigma_mm(w["width_mm"], texel_mm) for w in narrow]
        kept = [sigma / sigma_eff for sigma, sigma_eff in kept]
        notes.append(f"{len(narrow)} of {len(wrinkles)} wrinkles are narrower than the "
                     f"{texel_mm:.2f} mm texel (down to {min(w['width_mm'] for w in narrow):g} mm): "
                     "the displacement map holds their texel average, "
                     + (f"{min(kept):.2f}" if np.isclose(min(kept), max(kept), atol=5e-3)
                        else f"{min(kept):.2f}-{max(kept):.2f}") + " of their depth")
    if pores and pores["density_per_cm2"] > 0 and pores["depth_mm"] > 0 and pores["diameter_mm"] < texel_mm:
        sigma, sigma_eff = texel_sigma_mm(pores["diameter_mm"], texel_mm)
        notes.append(f"pores are {pores['diameter_mm']:g} mm wide, below the {texel_mm:.2f} mm texel: "
                     f"the displacement map holds their texel average, {(sigma / sigma_eff) ** 2:.2f} "
                     "of their depth")
    return notes


def check_wrinkle(wrinkle, where="wrinkle"):
    """``ValueError`` naming ``where`` and the key unless ``wrinkle`` is a valid wrinkle dict."""
    check_object_keys(wrinkle, where, "a wrinkle", WRINKLE_KEYS, ("path_uv", "depth_mm", "width_mm"))
    for key in ("depth_mm", "width_mm"):
        value = wrinkle[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
            raise ValueError(f"{where}.{key}: must be a number > 0, got {value!r}")
    path = wrinkle["path_uv"]
    ok = isinstance(path, (list, tuple)) and len(path) >= 2 and all(
        isinstance(point, (list, tuple)) and len(point) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and 0.0 <= x <= 1.0 for x in point)
        for point in path)
    if not ok:
        raise ValueError(f"{where}.path_uv: must be a list of at least two [u, v] pairs in [0, 1], "
                         f"got {path!r}")


def check_pores(pores, where="pores"):
    """``ValueError`` naming ``where`` and the key unless ``pores`` is a valid pores dict."""
    check_object_keys(pores, where, "pores", PORE_KEYS, tuple(PORE_KEYS))
    for key, positive in (("density_per_cm2", False), ("diameter_mm", True), ("depth_mm", False)):
        value = pores[key]
        bad = isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value)
        if bad or value < 0 or (positive and value == 0):
            raise ValueError(f"{where}.{key}: must be a number {'>' if positive else '>='} 0, got {value!r}")


def relief_depth(atlas, wrinkles, pores, rng):
    """``(depth, notes)``: the (T, T) depth (mm, >= 0, 0 off the mesh) the wrinkles and pores
    carve, and :func:`unresolved_features`' sentences. ``rng`` draws the pores' centres."""
    valid = np.asarray(atlas.valid, bool)
    texel_mm = float(np.median(atlas.texel_size_mm[valid]))
    depth = np.zeros(valid.shape)
    for wrinkle in wrinkles:
        depth += wrinkle_depth(atlas, wrinkle, texel_mm)
    if pores:
        depth += pore_depth(atlas, pores, texel_mm, rng)
    return depth, unresolved_features(wrinkles, pores, texel_mm)
