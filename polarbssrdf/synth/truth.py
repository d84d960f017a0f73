"""Ground-truth appearance maps for synthetic captures.

Every map is a smooth random field in texture space around a base value:
white noise filtered by a Gaussian of ``correlation_mm`` (through the mean
texel size), scaled to a standard deviation and clipped to the parameter's
valid range. The biophysical maps start from a row of the supplement's
Table 2, or from bases of their own (:func:`table2_offset_settings` moves
them off the row's means by a number of Table 2 spreads); localized features
(freckles, a patch of dermal blood: :data:`FEATURE_KEYS`) multiply a map
inside smooth-edged disks on the surface; wrinkles and pores are carved into
the displacement (:mod:`polarbssrdf.synth.microgeometry`); a dynamic sequence
varies the hemoglobin fractions over frames.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
from scipy.ndimage import gaussian_filter

from polarbssrdf.io.jsonfile import check_object_keys
from polarbssrdf.skin.parameters import TABLE2, TABLE2_STD, table2_spread_across_rows
from polarbssrdf.synth.microgeometry import (
    DEFAULT_PORES,
    check_pores,
    check_wrinkle,
    face_wrinkle_paths,
    relief_depth,
    unresolved_features,
)

# name -> (base, standard deviation, lower bound, upper bound)
DEFAULT_REFLECTANCE = {
    "eta": (1.42, 0.015, 1.3, 1.6),
    "alpha_s": (0.55, 0.03, 0.05, 1.0),
    "alpha_ss": (0.97, 0.01, 0.05, 1.0),
    "rho_s": (0.8, 0.1, 0.0, 1.0),
    "rho_ss": (0.3, 0.05, 0.0, 1.0),
    "displacement": (0.0, 0.1, -1.0, 1.0),  # mm
}
BIOPHYSICAL = ("C_m", "beta_m", "C_h_out", "C_h_in")
DEFAULT_BIOPHYSICAL_STD = {"C_m": 0.004, "beta_m": 0.01, "C_h_out": 0.01, "C_h_in": 0.008}
DEFAULT_SKIN_LAYERS = {
    # the epidermis of the Donner & Jensen 2006 two-layer model; high-frequency ultrasound of
    # 118 faces gives 0.17-0.22 mm per site with a between-subject SD of 0.02-0.03 mm
    # (Meng et al., BMC Medical Imaging 22:113, 2022, Table 2); OCT and histology give thinner
    # epidermis (0.03-0.07 mm), so the thickness is a model parameter, not a measurement
    "thickness_mm": (0.25, 0.025, 0.10, 0.40),
    # the oxygen fraction of cutaneous blood: 0.75 in Donner et al. 2008 and Jacques' 2013
    # review (Phys. Med. Biol. 58 R37); arterial 0.95-0.98, venous 0.6-0.75
    "gamma": (0.75, 0.03, 0.50, 0.95),
}
"""``name -> (base, std, low, high)`` of the skin's other unknowns (mm; fraction), drawn as maps."""
SKIN_LAYERS = tuple(DEFAULT_SKIN_LAYERS)
MAP_NAMES = tuple(DEFAULT_REFLECTANCE) + BIOPHYSICAL + SKIN_LAYERS
BIOPHYSICAL_LIMITS = (0.0, 1.0)
"""Default ``[low, high]`` of a biophysical map: volume fractions."""

FACE_WRINKLES = "face"
"""``TruthSettings.wrinkles`` meaning the embedded face's default furrows."""

FEATURE_KEYS = {
    "map": "the biophysical map it changes (C_m, beta_m, C_h_out or C_h_in)",
    "factor": "the map is multiplied by this at the centre of each disk (> 0)",
    "diameter_mm": "diameter of each disk on the surface, mm (> 0)",
    "edge_mm": "width of the disk's soft edge (logistic), mm (> 0; default diameter / 10)",
    "count": "number of disks at random surface points (uniform by area), or",
    "centers_uv": "explicit disk centres, a list of [u, v] texture coordinates in [0, 1]",
    "name": "an optional label for the record",
}
"""Keys of one localized feature (``TruthSettings.features``), as docs/synth.md lists them."""


@dataclasses.dataclass(frozen=True)
class TruthSettings:
    """What the synthetic face or sphere is made of.

    Attributes
    ----------
    reflectance : dict
        ``name -> (base, std, low, high)`` for eta, alpha_s, alpha_ss, rho_s,
        rho_ss and displacement (mm).
    skin : (region, type)
        Row of Table 2 for the biophysical base values, e.g. ("forehead", "II").
    biophysical_std : dict
        Standard deviation of each biophysical map (absolute fractions), for
        maps that ``biophysical`` does not give.
    correlation_mm : float
        Correlation length of the random fields, mm.
    hemoglobin_swing : float
        Relative peak change of C_h_out and C_h_in over a dynamic sequence.
    biophysical : dict
        ``name -> (base, std, low, high)`` (volume fractions, ``0 <= low <=
        base <= high <= 1``) for the biophysical maps that should not follow
        the ``skin`` row; the others take the row's mean, ``biophysical_std``
        and [0, 1] (:meth:`biophysical_maps`).
    features : list of dict
        Localized features applied after the random fields, in order: each
        multiplies one biophysical map inside smooth-edged disks on the
        surface (keys in :data:`FEATURE_KEYS`; :func:`feature_weight`).
    skin_layers : dict
        ``name -> (base, std, low, high)`` of the epidermal thickness (``thickness_mm``,
        mm) and the blood's oxygen fraction (``gamma``) maps; defaults
        :data:`DEFAULT_SKIN_LAYERS` (cited there). Drawn after the features, so settings
        that leave them at their defaults keep the other maps.
    wrinkles : "face" or list of dict
        Furrows carved into the displacement map
        (:mod:`polarbssrdf.synth.microgeometry`; keys in
        :data:`~polarbssrdf.synth.microgeometry.WRINKLE_KEYS`). ``"face"`` (the
        default): the embedded face's forehead lines, crow's feet and nasolabial folds
        (:func:`~polarbssrdf.synth.microgeometry.face_wrinkle_paths`), none on an
        object without the face's landmarks (the sphere); ``[]``: none.
    pores : dict or None
        Pits carved into the displacement map at a density per cm^2 (keys in
        :data:`~polarbssrdf.synth.microgeometry.PORE_KEYS`; default
        :data:`~polarbssrdf.synth.microgeometry.DEFAULT_PORES`); None: none. Their
        centres are drawn last, so the other maps do not change with them.
    """

    reflectance: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_REFLECTANCE))
    skin: tuple = ("forehead", "II")
    biophysical_std: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_BIOPHYSICAL_STD))
    correlation_mm: float = 8.0
    hemoglobin_swing: float = 0.3
    biophysical: dict = dataclasses.field(default_factory=dict)
    features: list = dataclasses.field(default_factory=list)
    skin_layers: dict = dataclasses.field(default_factory=lambda: dict(DEFAULT_SKIN_LAYERS))
    wrinkles: object = FACE_WRINKLES
    pores: dict | None = dataclasses.field(default_factory=lambda: dict(DEFAULT_PORES))

    def __post_init__(self):
        if tuple(self.skin) not in TABLE2:
            raise ValueError(f"skin must be one of {sorted(TABLE2)}, got {self.skin!r}")
        for name, value in self.reflectance.items():
            if name not in DEFAULT_REFLECTANCE:
                raise ValueError(f"unknown reflectance map {name!r}; known: {list(DEFAULT_REFLECTANCE)}")
            if len(value) != 4:
                raise ValueError(f"{name}: expected [base, std, low, high], got {list(value)}")
            base, std, low, high = value
            if not (low <= base <= high) or std < 0:
                raise ValueError(f"{name}: base {base} outside [{low}, {high}] or negative std")
        if set(self.biophysical_std) != set(BIOPHYSICAL):
            raise ValueError(f"biophysical_std must give {list(BIOPHYSICAL)}, got "
                             f"{sorted(self.biophysical_std)}")
        if any(std < 0 for std in self.biophysical_std.values()):
            raise ValueError(f"biophysical_std must be >= 0, got {self.biophysical_std}")
        for name, value in self.biophysical.items():
            check_field_spec("biophysical", name, value, BIOPHYSICAL, (0.0, 1.0))
        for index, feature in enumerate(self.features):
            check_feature(feature, f"features[{index}]")
        for name, value in self.skin_layers.items():
            check_field_spec("skin_layers", name, value, DEFAULT_SKIN_LAYERS,
                             (0.02, 1.0) if name == "thickness_mm" else (0.0, 1.0))
        if self.correlation_mm <= 0:
            raise ValueError("correlation_mm must be > 0")
        if self.wrinkles != FACE_WRINKLES:
            if not isinstance(self.wrinkles, (list, tuple)):
                raise ValueError(f"wrinkles must be {FACE_WRINKLES!r} or a list of objects, got "
                                 f"{self.wrinkles!r}")
            for index, wrinkle in enumerate(self.wrinkles):
                check_wrinkle(wrinkle, f"wrinkles[{index}]")
        if self.pores is not None:
            check_pores(self.pores)

    def wrinkle_list(self, landmarks=None):
        """The wrinkles as a list: ``"face"`` becomes the face's default paths when the
        ``landmarks`` mesh (the canonical face) is given, else none."""
        if self.wrinkles == FACE_WRINKLES:
            return face_wrinkle_paths(landmarks) if landmarks is not None else []
        return list(self.wrinkles)

    def biophysical_maps(self):
        """``name -> (base, std, low, high)`` of the four biophysical maps as they are drawn."""
        row = TABLE2[tuple(self.skin)]
        defaults = {name: (getattr(row, name), self.biophysical_std[name]) + BIOPHYSICAL_LIMITS
                    for name in BIOPHYSICAL}
        return {name: tuple(self.biophysical.get(name, defaults[name])) for name in BIOPHYSICAL}

    def skin_parameters(self):
        """The Table 2 row's :class:`~polarbssrdf.skin.SkinParameters` with the maps' bases:
        the skin whose layer profiles synth blurs with (the row itself by default)."""
        bases = {name: value[0] for name, value in self.biophysical_maps().items()}
        bases.update({name: value[0] for name, value in self.layer_maps().items()})
        return dataclasses.replace(TABLE2[tuple(self.skin)], **bases)

    def layer_maps(self):
        """``name -> (base, std, low, high)`` of the thickness and oxygenation maps as they are drawn."""
        return {name: tuple(self.skin_layers.get(name, DEFAULT_SKIN_LAYERS[name])) for name in SKIN_LAYERS}


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)


def check_field_spec(group, name, value, known, limits):
    """A ``[base, std, low, high]`` entry ``name`` of ``group`` (a truth field: its face value,
    spread and clip range): ``ValueError`` naming both unless ``name`` is in ``known``, the four
    are numbers, ``std >= 0`` and ``limits[0] <= low <= base <= high <= limits[1]``."""
    if name not in known:
        raise ValueError(f"{group}: unknown map {name!r}; known: {list(known)}")
    if isinstance(value, str) or len(value) != 4 or not all(_is_number(x) for x in value):
        raise ValueError(f"{group} {name}: expected [base, std, low, high], got {value!r}")
    base, std, low, high = value
    if std < 0:
        raise ValueError(f"{group} {name}: std must be >= 0, got {std}")
    if not (limits[0] <= low <= base <= high <= limits[1]):
        raise ValueError(f"{group} {name}: need {limits[0]} <= low <= base <= high <= {limits[1]}, "
                         f"got [{base}, {std}, {low}, {high}]")


def check_feature(feature, where="feature"):
    """``ValueError`` naming ``where`` and the key if ``feature`` is not a valid feature dict."""
    check_object_keys(feature, where, "a feature", FEATURE_KEYS, ("map", "factor", "diameter_mm"))
    if feature["map"] not in BIOPHYSICAL:
        raise ValueError(f"{where}.map: {feature['map']!r} is not one of {list(BIOPHYSICAL)}")
    for key in ("factor", "diameter_mm", "edge_mm"):
        if key in feature and not (_is_number(feature[key]) and feature[key] > 0):
            raise ValueError(f"{where}.{key}: must be a number > 0, got {feature[key]!r}")
    if ("count" in feature) == ("centers_uv" in feature):
        raise ValueError(f"{where}: give exactly one of 'count' and 'centers_uv'")
    if "count" in feature:
        count = feature["count"]
        if isinstance(count, bool) or not isinstance(count, int) or count < 0:
            raise ValueError(f"{where}.count: must be an integer >= 0, got {count!r}")
    else:
        centres = np.asarray(feature["centers_uv"], dtype=object)
        ok = centres.ndim == 2 and centres.shape[1] == 2 and all(
            _is_number(x) and 0.0 <= x <= 1.0 for x in centres.ravel())
        if not ok:
            raise ValueError(f"{where}.centers_uv: must be a list of [u, v] pairs in [0, 1], "
                             f"got {feature['centers_uv']!r}")


def load_settings(path):
    """Settings from a JSON file: any subset of the fields of :class:`TruthSettings`.

    ``reflectance``, ``biophysical_std`` and ``biophysical`` may give only
    some maps; the others keep their defaults. A biophysical map given in both
    ``biophysical`` and ``biophysical_std`` is refused (two standard
    deviations). The keys are documented in ``docs/synth.md``.
    """
    from polarbssrdf.io.jsonfile import read_json_file

    path = pathlib.Path(path)
    data = read_json_file(path, "parameter file")
    if not isinstance(data, dict):
        raise ValueError(f"{path}: settings must be a JSON object")
    unknown = set(data) - {f.name for f in dataclasses.fields(TruthSettings)}
    if unknown:
        raise ValueError(f"{path}: unknown settings {sorted(unknown)}")
    for key in ("reflectance", "biophysical_std", "biophysical", "skin_layers"):
        if key in data and not isinstance(data[key], dict):
            raise ValueError(f"{path}: {key} must be an object of maps")
    if "reflectance" in data:
        data["reflectance"] = {**DEFAULT_REFLECTANCE,
                               **{k: tuple(v) for k, v in data["reflectance"].items()}}
    for key in ("biophysical_std", "biophysical"):
        unknown = set(data.get(key, {})) - set(BIOPHYSICAL)
        if unknown:
            raise ValueError(f"{path}: unknown biophysical maps in {key} {sorted(unknown)}; known: "
                             f"{list(BIOPHYSICAL)}")
    twice = sorted(set(data.get("biophysical_std", {})) & set(data.get("biophysical", {})))
    if twice:
        raise ValueError(f"{path}: {twice} in both biophysical and biophysical_std; give the "
                         "standard deviation once, in biophysical's [base, std, low, high]")
    if "biophysical_std" in data:
        data["biophysical_std"] = {**DEFAULT_BIOPHYSICAL_STD, **data["biophysical_std"]}
    if "biophysical" in data:
        data["biophysical"] = {k: tuple(v) if isinstance(v, list) else v
                               for k, v in data["biophysical"].items()}
    if "skin_layers" in data:
        unknown = set(data["skin_layers"]) - set(SKIN_LAYERS)
        if unknown:
            raise ValueError(f"{path}: unknown skin layer maps {sorted(unknown)}; known: {list(SKIN_LAYERS)}")
        data["skin_layers"] = {**DEFAULT_SKIN_LAYERS, **{k: tuple(v) if isinstance(v, list) else v
                                                        for k, v in data["skin_layers"].items()}}
    if "features" in data and not isinstance(data["features"], list):
        raise ValueError(f"{path}: features must be a list of objects")
    if "wrinkles" in data and data["wrinkles"] != FACE_WRINKLES and not isinstance(data["wrinkles"], list):
        raise ValueError(f"{path}: wrinkles must be {FACE_WRINKLES!r} or a list of objects")
    if "skin" in data:
        data["skin"] = tuple(data["skin"])
    try:
        return TruthSettings(**data)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def table2_offset_settings(skin, spreads=1.0, signs=None, spread="row", **fields):
    """Truth settings of a Table 2 row whose biophysical bases sit off the row's means.

    ``base = mean + sign * spreads * s`` per map, where ``s`` is, with
    ``spread="row"`` (default), the row's own Table 2 "(std)"
    (:data:`~polarbssrdf.skin.parameters.TABLE2_STD`: how much the map varies
    over the measured region, the spread a prior centred on that row would
    carry), or with ``spread="rows"`` the standard deviation of the eight
    Table 2 means (:func:`~polarbssrdf.skin.parameters.table2_spread_across_rows`,
    the spread of a population prior over skin types; 2-10x larger).

    Parameters
    ----------
    skin : (region, type)
        The Table 2 row.
    spreads : float
        How many spreads to move each base (>= 0).
    signs : dict, optional
        ``name -> +1 or -1`` per map; default +1 for all: a downward shift of
        ``C_h_in`` or ``beta_m`` by one spread leaves most rows' bases within two
        map standard deviations of 0, where the field would be clipped.
    spread : {"row", "rows"}
    **fields
        Other :class:`TruthSettings` fields (``biophysical_std``, ``features``, ...).

    A base closer than two map standard deviations to 0 or 1 (where more than about 2% of
    the field would be clipped) is refused with a ``ValueError`` naming the map. The maps
    keep ``biophysical_std`` (or the default) as their spatial spread.
    """
    skin = tuple(skin)
    if skin not in TABLE2:
        raise ValueError(f"skin must be one of {sorted(TABLE2)}, got {skin!r}")
    if not (_is_number(spreads) and spreads >= 0):
        raise ValueError(f"spreads must be a number >= 0, got {spreads!r}")
    if spread == "row":
        scale = TABLE2_STD[skin]
    elif spread == "rows":
        scale = table2_spread_across_rows()
    else:
        raise ValueError(f"spread must be 'row' or 'rows', got {spread!r}")
    signs = {**DEFAULT_OFFSET_SIGNS, **(signs or {})}
    unknown = sorted(set(signs) - set(BIOPHYSICAL))
    if unknown or any(value not in (-1, 1) for value in signs.values()):
        raise ValueError(f"signs must map {list(BIOPHYSICAL)} to +1 or -1, got {signs}")
    std = {**DEFAULT_BIOPHYSICAL_STD, **fields.pop("biophysical_std", {})}
    biophysical = {}
    for name in BIOPHYSICAL:
        base = getattr(TABLE2[skin], name) + signs[name] * spreads * scale[name]
        if not 2.0 * std[name] <= base <= 1.0 - 2.0 * std[name]:
            raise ValueError(f"{name}: the mean {getattr(TABLE2[skin], name)} moved by "
                             f"{signs[name] * spreads:+g} x {scale[name]} is {base:.5f}, within two map "
                             f"standard deviations ({std[name]}) of [0, 1]'s ends; use the other sign, "
                             "fewer spreads or a smaller biophysical_std")
        biophysical[name] = (float(base), float(std[name])) + BIOPHYSICAL_LIMITS
    return TruthSettings(skin=skin, biophysical=biophysical, **fields)


DEFAULT_OFFSET_SIGNS = {"C_m": 1, "beta_m": 1, "C_h_out": 1, "C_h_in": 1}
"""Directions of :func:`table2_offset_settings`' shifts when none are given."""


def smooth_field(shape, correlation_texels, rng):
    """Unit-variance smooth random field (Gaussian-filtered white noise)."""
    field = gaussian_filter(rng.standard_normal(shape), correlation_texels, mode="wrap")
    return field / max(field.std(), 1e-12)


def truth_maps(atlas, settings, rng, landmarks=None):
    """The static maps (T x T float32) of every parameter in :data:`MAP_NAMES`.

    The random fields are drawn first, in a fixed order, and the features'
    random centres after them, so settings without features give the same maps
    as before features existed. The wrinkles and pores are carved into the
    displacement last (their pores' centres drawn last); ``landmarks``: the
    canonical face mesh when the atlas is the face's, for the default wrinkles
    (:meth:`TruthSettings.wrinkle_list`)."""
    texel_mm = float(np.median(atlas.texel_size_mm[atlas.valid]))
    correlation = settings.correlation_mm / texel_mm
    shape = atlas.valid.shape
    maps = {}
    for name, (base, std, low, high) in settings.reflectance.items():
        field = np.clip(base + std * smooth_field(shape, correlation, rng), low, high)
        # texels off the surface keep the base value: valid, and never seen
        maps[name] = np.where(atlas.valid, field, base)
    limits = settings.biophysical_maps()
    for name in BIOPHYSICAL:
        base, std, low, high = limits[name]
        field = np.clip(base + std * smooth_field(shape, correlation, rng), low, high)
        maps[name] = np.where(atlas.valid, field, base)
    for feature in settings.features:
        name = feature["map"]
        weight = feature_weight(atlas, feature, rng)
        _, _, low, high = limits[name]
        changed = np.clip(maps[name] * (1.0 + (feature["factor"] - 1.0) * weight), low, high)
        maps[name] = np.where(atlas.valid, changed, maps[name])
    for name, (base, std, low, high) in settings.layer_maps().items():
        field = np.clip(base + std * smooth_field(shape, correlation, rng), low, high)
        maps[name] = np.where(atlas.valid, field, base)
    depth, _ = relief_depth(atlas, settings.wrinkle_list(landmarks), settings.pores, rng)
    _, _, low, high = settings.reflectance["displacement"]
    maps["displacement"] = np.where(atlas.valid, np.clip(maps["displacement"] - depth, low, high),
                                    maps["displacement"])
    return {name: value.astype(np.float32) for name, value in maps.items()}


def relief_notes(atlas, settings, landmarks=None):
    """What of the wrinkles and pores the texture cannot hold
    (:func:`~polarbssrdf.synth.microgeometry.unresolved_features`), for synth to say."""
    texel_mm = float(np.median(atlas.texel_size_mm[atlas.valid]))
    return unresolved_features(settings.wrinkle_list(landmarks), settings.pores, texel_mm)


def feature_centres(atlas, feature, rng):
    """(n, 3) surface points (mm) of a feature's disk centres.

    ``centers_uv``: the surface point of the texel holding each (u, v) (the
    nearest surface texel if that one is off the mesh); ``count``: texels drawn
    from ``rng`` with probability proportional to their area, so the disks are
    uniform over the surface."""
    valid = atlas.valid
    T = valid.shape[0]
    positions = atlas.position[valid].astype(np.float64)
    if "count" in feature:
        area = np.prod(atlas.texel_size_mm[valid].astype(np.float64), axis=-1)
        picks = rng.choice(positions.shape[0], size=feature["count"], p=area / area.sum())
        return positions[picks]
    rows, cols = np.nonzero(valid)
    centres = []
    for u, v in feature["centers_uv"]:
        # Mitsuba uv: column j at u = (j + 0.5) / T, row i at v (polarbssrdf.geometry)
        i, j = min(int(v * T), T - 1), min(int(u * T), T - 1)
        nearest = int(np.argmin((rows - i) ** 2 + (cols - j) ** 2))
        centres.append(positions[nearest])
    return np.asarray(centres).reshape(-1, 3)


def disk_weight(distance_mm, diameter_mm, edge_mm):
    """Smooth-edged disk, 1 at the centre: ``L(r) / L(0)``, ``L(r) = 1 / (1 + exp((r - d/2) / e))``.

    ``distance_mm`` from the centre, ``diameter_mm`` d (the weight is 1/2 at
    r = d/2 relative to the centre's), ``edge_mm`` e (the 12%-88% rise takes 4 e)."""
    radius = 0.5 * diameter_mm
    logistic = lambda r: 0.5 * (1.0 - np.tanh(0.5 * (r - radius) / edge_mm))  # noqa: E731 (overflow-free)
    return logistic(np.asarray(distance_mm, dtype=np.float64)) / logistic(0.0)


def feature_weight(atlas, feature, rng):
    """(T, T) weight in [0, 1] of one feature: the largest :func:`disk_weight` over its disks,
    with distances between surface points in mm (straight lines, close to the surface's own
    over a few cm). Overlapping disks do not compound."""
    weight = np.zeros(atlas.valid.shape)
    points = atlas.position.astype(np.float64)
    edge = feature.get("edge_mm", 0.1 * feature["diameter_mm"])
    for centre in feature_centres(atlas, feature, rng):
        distance = np.linalg.norm(points - centre, axis=-1)
        weight = np.maximum(weight, disk_weight(distance, feature["diameter_mm"], edge))
    return np.where(atlas.valid, weight, 0.0)


def frame_maps(static, frame, n_frames, settings, flush_region=None):
    """Maps of ``frame``: hemoglobin rises over the sequence (a flush), peaking at the last frame.

    ``C_h = C_h(frame 0) (1 + swing sin(pi/2 frame / (n_frames - 1)) flush)``.

    Parameters
    ----------
    static : dict
        Maps of frame 0 (:func:`truth_maps`).
    flush_region : (T, T) float array, optional
        Where the skin flushes (weight in [0, 1]); everywhere by default.
    """
    if n_frames <= 1 or frame == 0:
        return dict(static)
    phase = np.sin(0.5 * np.pi * frame / (n_frames - 1))
    weight = 1.0 if flush_region is None else flush_region
    factor = 1.0 + settings.hemoglobin_swing * phase * weight
    maps = dict(static)
    limits = settings.biophysical_maps()
    for name in ("C_h_out", "C_h_in"):
        _, _, low, high = limits[name]
        maps[name] = np.clip(static[name] * factor, low, high).astype(np.float32)
    return maps
