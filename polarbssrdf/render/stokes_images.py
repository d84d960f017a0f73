"""Stokes and analyser images from a Mitsuba ``stokes`` render, and their PNG previews.

Mitsuba's ``stokes`` integrator writes, after the film's own channels
(``Y`` for ``pixel_format`` luminance, ``R, G, B`` for rgb, ...), the four
Stokes components as AOVs named ``S0.R, S0.G, S0.B, S1.R, ..., S3.B`` in the
image frame (x = image right, y = image up). In monochrome variants the three
colour copies are identical, so a component becomes one channel (``S0``); in
RGB and spectral variants it keeps its colours (``S0.R``, ``S0.G``,
``S0.B``). The analyser images ``I0, I45, I90, I135`` follow from
:func:`polarbssrdf.optics.stokes.polarization_images` (eq. 21).

Previews are 8-bit sRGB PNG arrays: the four analyser images tonemapped with
one shared exposure, ``S1`` and ``S2`` in a diverging colormap over one
symmetric range, DoLP on a fixed 0-1 scale, AoLP in a cyclic colormap over
(-90, 90] degrees, and a labelled 2 x 2 contact sheet of the analyser images.
The written S1, S2, DoLP and AoLP PNGs carry a title and a colour bar with
tick labels (:func:`with_colour_bar`), so they can be read without
``render.json``.

The analyser previews show the render as a camera would record it (exposure
1, values above 1 clip) whenever its white point, the 99.5th percentile of
the analyser values, lies in ``[AS_RENDERED_WHITE_MIN, 1]``: then a
scene's own exposure is what the preview shows. Renders outside that range
(in other units, or over-exposed) are scaled so that their white point is
displayed as white. ``render.json`` records which (``exposure_mode``).
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from polarbssrdf.io.atomic import atomic_write_bytes
from polarbssrdf.optics.stokes import (
    angle_of_linear_polarization,
    degree_of_linear_polarization,
    polarization_images,
)

__all__ = [
    "ANALYSER_CHANNELS",
    "AS_RENDERED_WHITE_MIN",
    "CONTACT_SHEET_FILE",
    "COLOUR_SUFFIXES",
    "ColourScale",
    "PREVIEW_FILES",
    "STOKES_COMPONENTS",
    "analyser_images",
    "channel_suffixes",
    "colour_scales",
    "contact_sheet",
    "false_colour",
    "luminance",
    "png_bytes",
    "polarization_channels",
    "preview_images",
    "preview_settings",
    "render_channel_names",
    "split_stokes",
    "srgb_encode",
    "tonemap_srgb",
    "with_colour_bar",
    "write_previews",
]

STOKES_COMPONENTS = ("S0", "S1", "S2", "S3")
"""Names of the Stokes components, in order."""

ANALYSER_CHANNELS = ("I0", "I45", "I90", "I135")
"""Names of the analyser images at 0, 45, 90 and 135 degrees from image right."""

COLOUR_SUFFIXES = (".R", ".G", ".B")
"""Channel-name suffixes of the colour copies in RGB and spectral variants."""

LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)
"""Rec. 709 weights of R, G, B used to reduce colour Stokes images for previews."""

PREVIEW_FILES = {name: f"{name}.png" for name in (*ANALYSER_CHANNELS, "S1", "S2", "DoLP", "AoLP")}
"""Preview name -> PNG file name written by :func:`write_previews`."""

CONTACT_SHEET_FILE = "preview.png"
"""File name of the 2 x 2 contact sheet of the analyser images."""

AS_RENDERED_WHITE_MIN = 1.0 / 16.0
"""Lowest white point (99.5th percentile of I0..I135) still previewed at exposure 1.

Below it the render is too dark to judge as recorded (or in other units) and
is auto-exposed instead; above 1 it would clip and is scaled down.
"""


# --------------------------------------------------------------------------
# Channels
# --------------------------------------------------------------------------

def render_channel_names(film) -> list[str]:
    """Names of the channels of the last image developed by a Mitsuba film.

    Parameters
    ----------
    film:
        ``scene.sensors()[i].film()`` after :func:`mitsuba.render`.

    Returns
    -------
    list of str
        One name per channel of the rendered tensor, e.g. ``['Y', 'S0.R',
        'S0.G', 'S0.B', 'S1.R', ...]`` for a luminance film with ``stokes``.
    """
    return [field.name for field in film.bitmap().struct_()]


def _find_channel(name: str, index: Mapping[str, int], channel_names: Sequence[str]) -> int:
    """Index of channel ``name`` in the render, or an error listing the channels present."""
    if name not in index:
        raise ValueError(
            f"the render has no channel '{name}' (its channels are: {', '.join(channel_names)}); "
            "Stokes images need the 'stokes' integrator in a polarized variant")
    return index[name]


def split_stokes(image, channel_names: Sequence[str], monochrome: bool) -> dict[str, np.ndarray]:
    """The Stokes images ``S0..S3`` of a ``stokes`` render, as named float32 channels.

    Parameters
    ----------
    image:
        The render: a Mitsuba ``TensorXf`` or NumPy array of shape
        H x W x C (radiance units of the scene).
    channel_names:
        The C channel names (:func:`render_channel_names`).
    monochrome:
        ``True`` for monochrome variants: each component becomes one channel
        (``S0``), taken from its ``.R`` copy (all three copies are equal).
        ``False``: three channels per component (``S0.R``, ``S0.G``, ``S0.B``).

    Returns
    -------
    dict
        ``S0, S1, S2, S3`` (or ``S0.R, S0.G, S0.B, S1.R, ...``) -> H x W
        C-contiguous float32 arrays.
    """
    pixels = np.asarray(image, dtype=np.float32)
    if pixels.ndim != 3:
        raise ValueError(f"expected an H x W x C render, got an array of shape {pixels.shape}")
    if pixels.shape[2] != len(channel_names):
        raise ValueError(f"the render has {pixels.shape[2]} channels but {len(channel_names)} "
                         f"channel names were given ({', '.join(channel_names)})")
    index = {name: i for i, name in enumerate(channel_names)}
    stokes = {}
    for component in STOKES_COMPONENTS:
        suffixes = (".R",) if monochrome else COLOUR_SUFFIXES
        for suffix in suffixes:
            i = _find_channel(component + suffix, index, channel_names)
            name = component if monochrome else component + suffix
            stokes[name] = np.ascontiguousarray(pixels[:, :, i])
    return stokes


def channel_suffixes(channels: Mapping[str, np.ndarray], base: str = "S0") -> tuple[str, ...]:
    """The colour suffixes present for ``base``: ``("",)`` if monochrome, else ``.R/.G/.B``.

    Parameters
    ----------
    channels:
        Named channels such as the output of :func:`split_stokes`.
    base:
        The component to look for (default ``S0``).
    """
    if base in channels:
        return ("",)
    if all(base + suffix in channels for suffix in COLOUR_SUFFIXES):
        return COLOUR_SUFFIXES
    raise ValueError(f"no channel '{base}' or '{base}.R/.G/.B' among {', '.join(channels)}")


def analyser_images(stokes: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The analyser images ``I0, I45, I90, I135`` from Stokes images (eq. 21).

    Parameters
    ----------
    stokes:
        ``S0..S3`` channels as returned by :func:`split_stokes` (monochrome
        or with ``.R/.G/.B`` suffixes).

    Returns
    -------
    dict
        ``I0, I45, I90, I135`` (with the same colour suffixes) -> float32
        arrays, in the units of ``S0``.
    """
    suffixes = channel_suffixes(stokes)
    per_colour = {s: polarization_images(tuple(stokes[c + s] for c in STOKES_COMPONENTS))
                  for s in suffixes}
    # Ordered by angle first, then colour: I0.R, I0.G, I0.B, I45.R, ...
    return {name + s: np.ascontiguousarray(per_colour[s][i], dtype=np.float32)
            for i, name in enumerate(ANALYSER_CHANNELS) for s in suffixes}


def polarization_channels(image, channel_names: Sequence[str], monochrome: bool
                          ) -> dict[str, np.ndarray]:
    """Analyser and Stokes images of a ``stokes`` render, ready for :func:`write_exr`.

    Parameters
    ----------
    image, channel_names, monochrome:
        As for :func:`split_stokes`.

    Returns
    -------
    dict
        ``I0, I45, I90, I135, S0, S1, S2, S3`` (colour-suffixed in colour
        variants) -> H x W float32 arrays.
    """
    stokes = split_stokes(image, channel_names, monochrome)
    return {**analyser_images(stokes), **stokes}


# --------------------------------------------------------------------------
# Previews
# --------------------------------------------------------------------------

def luminance(channels: Mapping[str, np.ndarray], base: str) -> np.ndarray:
    """One H x W image for ``base``: the channel itself, or the Rec. 709 mix of ``.R/.G/.B``.

    Parameters
    ----------
    channels:
        Named channels.
    base:
        E.g. ``"S1"``.
    """
    suffixes = channel_suffixes(channels, base)
    if suffixes == ("",):
        return np.asarray(channels[base], dtype=np.float32)
    return sum(w * np.asarray(channels[base + s], dtype=np.float32)
               for w, s in zip(LUMINANCE_WEIGHTS, suffixes)).astype(np.float32)


def _colour_image(channels: Mapping[str, np.ndarray], base: str) -> np.ndarray:
    """H x W (monochrome) or H x W x 3 (colour) linear image of ``base``."""
    suffixes = channel_suffixes(channels, base)
    if suffixes == ("",):
        return np.asarray(channels[base], dtype=np.float32)
    return np.stack([channels[base + s] for s in suffixes], axis=-1).astype(np.float32)


def preview_settings(channels: Mapping[str, np.ndarray], percentile: float = 99.5) -> dict:
    """Display scales shared by all previews of one render.

    Parameters
    ----------
    channels:
        The output of :func:`polarization_channels`.
    percentile:
        Percentile (0-100) of the positive analyser values that is displayed
        as white, and of ``|S1|, |S2|`` that ends the diverging scale.

    Returns
    -------
    dict
        ``exposure`` (multiplier applied to I0..I135 before the sRGB curve),
        ``exposure_mode`` (``"as rendered"``: exposure 1, the white point lies
        in ``[AS_RENDERED_WHITE_MIN, 1]``; ``"auto"``: the white point is
        shown as white), ``white_point`` (the percentile value),
        ``stokes_range`` (S1 and S2 are shown over ``[-r, r]``) and
        ``s0_threshold`` (pixels with S0 at or below it have no DoLP/AoLP).
    """
    analysers = np.concatenate([luminance(channels, n).ravel() for n in ANALYSER_CHANNELS])
    positive = analysers[analysers > 0]
    white = float(np.percentile(positive, percentile)) if positive.size else 0.0
    as_rendered = white == 0.0 or AS_RENDERED_WHITE_MIN <= white <= 1.0
    linear = np.concatenate([np.abs(luminance(channels, n)).ravel() for n in ("S1", "S2")])
    linear = linear[linear > 0]
    stokes_range = float(np.percentile(linear, percentile)) if linear.size else 0.0
    s0 = luminance(channels, "S0")
    return {
        "exposure": 1.0 if as_rendered else 1.0 / white,
        "exposure_mode": "as rendered" if as_rendered else "auto",
        "white_point": white,
        "stokes_range": stokes_range if stokes_range > 0 else 1.0,
        "s0_threshold": 1e-6 * float(np.max(s0)) if np.max(s0) > 0 else 0.0,
        "percentile": percentile,
    }


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve of linear values, clipped to [0, 1] first."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def tonemap_srgb(image: np.ndarray, exposure: float) -> np.ndarray:
    """An 8-bit sRGB preview of a linear image.

    Parameters
    ----------
    image:
        H x W or H x W x 3 linear values (negative values show as black).
    exposure:
        Multiplier applied before the sRGB curve; values >= 1 after it clip.

    Returns
    -------
    numpy.ndarray
        uint8, H x W x 3.
    """
    encoded = np.rint(255.0 * srgb_encode(np.asarray(image) * exposure)).astype(np.uint8)
    if encoded.ndim == 2:
        encoded = np.repeat(encoded[:, :, None], 3, axis=2)
    return encoded


def false_colour(values: np.ndarray, cmap: str, vmin: float, vmax: float,
                 mask: np.ndarray | None = None) -> np.ndarray:
    """An 8-bit RGB false-colour image of a scalar H x W image.

    Parameters
    ----------
    values:
        H x W scalar image.
    cmap:
        Name of a Matplotlib colormap (e.g. ``RdBu_r``, ``viridis``, ``twilight``).
    vmin, vmax:
        The values shown at the two ends of the colormap (others clip).
    mask:
        Optional H x W boolean: pixels where it is ``False`` are black.

    Returns
    -------
    numpy.ndarray
        uint8, H x W x 3.
    """
    import matplotlib

    if not vmax > vmin:
        raise ValueError(f"false_colour needs vmax > vmin, got [{vmin}, {vmax}]")
    t = np.clip((np.asarray(values, dtype=np.float64) - vmin) / (vmax - vmin), 0.0, 1.0)
    rgb = matplotlib.colormaps[cmap](t)[..., :3]
    out = np.rint(255.0 * rgb).astype(np.uint8)
    if mask is not None:
        out[~np.asarray(mask, dtype=bool)] = 0
    return out


@dataclass(frozen=True)
class ColourScale:
    """How a scalar preview maps values to colours, and how its colour bar is labelled.

    Attributes
    ----------
    cmap:
        Matplotlib colormap name.
    vmin, vmax:
        Values at the two ends of the colormap.
    title:
        Quantity and unit, drawn above the preview.
    ticks:
        ``(value, label)`` pairs drawn beside the colour bar.
    """

    cmap: str
    vmin: float
    vmax: float
    title: str
    ticks: tuple[tuple[float, str], ...]


def _signed_ticks(r: float) -> tuple[tuple[float, str], ...]:
    """Ticks at -r, -r/2, 0, r/2, r with two significant digits."""
    return tuple((v, "0" if v == 0 else f"{v:.2g}") for v in (-r, -0.5 * r, 0.0, 0.5 * r, r))


def colour_scales(settings: Mapping) -> dict[str, ColourScale]:
    """The colour scales of the false-colour previews ``S1, S2, DoLP, AoLP``.

    Parameters
    ----------
    settings:
        The output of :func:`preview_settings` (its ``stokes_range``).
    """
    r = float(settings["stokes_range"])
    degrees = tuple((np.deg2rad(d), f"{d}\u00b0") for d in (-90, -45, 0, 45, 90))
    return {
        "S1": ColourScale("RdBu_r", -r, r, "S1 = I0 - I90 [radiance]", _signed_ticks(r)),
        "S2": ColourScale("RdBu_r", -r, r, "S2 = I45 - I135 [radiance]", _signed_ticks(r)),
        "DoLP": ColourScale("viridis", 0.0, 1.0, "DoLP [0-1]",
                            tuple((v, f"{v:g}") for v in (0.0, 0.25, 0.5, 0.75, 1.0))),
        "AoLP": ColourScale("twilight", -0.5 * np.pi, 0.5 * np.pi,
                            "AoLP [deg from image right]", degrees),
    }


def preview_images(channels: Mapping[str, np.ndarray], settings: Mapping) -> dict[str, np.ndarray]:
    """All preview images of a render, as uint8 H x W x 3 sRGB arrays.

    Parameters
    ----------
    channels:
        The output of :func:`polarization_channels`.
    settings:
        The output of :func:`preview_settings`.

    Returns
    -------
    dict
        ``I0, I45, I90, I135`` (tonemapped, one shared exposure), ``S1``,
        ``S2`` (``RdBu_r`` over ``[-stokes_range, stokes_range]``; red =
        positive), ``DoLP`` (``viridis``, 0 to 1) and ``AoLP`` (``twilight``,
        -90 to 90 degrees from image right), keyed as in :data:`PREVIEW_FILES`.
        DoLP and AoLP are black where S0 is (near) zero.
    """
    previews = {name: tonemap_srgb(_colour_image(channels, name), settings["exposure"])
                for name in ANALYSER_CHANNELS}
    S0, S1, S2 = (luminance(channels, n) for n in ("S0", "S1", "S2"))
    lit = S0 > settings["s0_threshold"]
    values = {"S1": (S1, None), "S2": (S2, None),
              "DoLP": (np.asarray(degree_of_linear_polarization(S0, S1, S2)), lit),
              "AoLP": (np.asarray(angle_of_linear_polarization(S1, S2)), lit)}
    for name, scale in colour_scales(settings).items():
        image, mask = values[name]
        previews[name] = false_colour(image, scale.cmap, scale.vmin, scale.vmax, mask=mask)
    return previews


def _label_font(size: int):
    """Pillow's built-in font at ``size`` pixels (the bitmap default on old Pillow)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def contact_sheet(tiles: Mapping[str, np.ndarray], columns: int = 2, min_tile: int = 192,
                  label_height: int = 18, gap: int = 2) -> np.ndarray:
    """A grid of labelled images (e.g. the four analyser previews, 2 x 2).

    Parameters
    ----------
    tiles:
        Label -> uint8 H x W x 3 image; all the same size. Filled row by row.
    columns:
        Tiles per row.
    min_tile:
        Small tiles are enlarged (nearest neighbour, integer factor) to at
        least this width in pixels, so that labels stay readable.
    label_height:
        Height in pixels of the label strip above each tile.
    gap:
        Pixels of background between tiles.

    Returns
    -------
    numpy.ndarray
        uint8 RGB contact sheet.
    """
    from PIL import Image, ImageDraw

    images = list(tiles.values())
    if not images:
        raise ValueError("contact_sheet needs at least one tile")
    height, width = images[0].shape[:2]
    if any(image.shape[:2] != (height, width) for image in images):
        raise ValueError("contact_sheet: all tiles must have the same size")
    scale = max(1, -(-min_tile // width))
    tile_w, tile_h = width * scale, height * scale
    rows = -(-len(images) // columns)
    cell_h = label_height + tile_h
    sheet = Image.new("RGB", (columns * tile_w + (columns + 1) * gap,
                              rows * cell_h + (rows + 1) * gap), (40, 40, 40))
    draw = ImageDraw.Draw(sheet)
    font = _label_font(max(8, label_height - 6))
    for k, (label, image) in enumerate(tiles.items()):
        x = gap + (k % columns) * (tile_w + gap)
        y = gap + (k // columns) * (cell_h + gap)
        draw.text((x + 4, y + 2), label, fill=(235, 235, 235), font=font)
        tile = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8), "RGB")
        sheet.paste(tile.resize((tile_w, tile_h), Image.NEAREST), (x, y + label_height))
    return np.asarray(sheet)


def with_colour_bar(image: np.ndarray, scale: ColourScale, min_height: int = 160,
                    title_height: int = 16, bar_width: int = 12) -> np.ndarray:
    """A false-colour preview with its title above and a labelled colour bar on the right.

    Parameters
    ----------
    image:
        uint8 H x W x 3 false-colour image made with ``scale``.
    scale:
        Its colour scale (:func:`colour_scales`).
    min_height:
        Small images are enlarged (nearest neighbour, integer factor) to at
        least this height in pixels, so that tick labels fit beside them.
    title_height:
        Height in pixels of the title strip.
    bar_width:
        Width in pixels of the colour bar.

    Returns
    -------
    numpy.ndarray
        uint8 RGB image, larger than ``image``.
    """
    import matplotlib
    from PIL import Image, ImageDraw

    height, width = image.shape[:2]
    factor = max(1, -(-min_height // height))
    font = _label_font(11)
    label_width = max(int(np.ceil(font.getlength(text))) for _, text in scale.ticks)
    margin = 6
    tick, gap = 3, 3  # tick mark, then a gap so that '0' does not read as '-0'
    panel = margin + bar_width + tick + gap + label_width + margin
    title_width = int(np.ceil(font.getlength(scale.title))) + 2 * 4
    canvas_w = max(width * factor + panel, title_width)
    canvas = Image.new("RGB", (canvas_w, title_height + height * factor), (40, 40, 40))
    draw = ImageDraw.Draw(canvas)
    draw.text((4, 2), scale.title, fill=(235, 235, 235), font=font)
    enlarged = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8), "RGB")
    canvas.paste(enlarged.resize((width * factor, height * factor), Image.NEAREST),
                 (0, title_height))

    # The bar spans the image height with vmax at the top, like a value axis.
    bar_h = height * factor - 2 * margin
    top, left = title_height + margin, width * factor + margin
    t = np.linspace(1.0, 0.0, bar_h)[:, None]
    colours = np.rint(255.0 * matplotlib.colormaps[scale.cmap](t)[..., :3]).astype(np.uint8)
    canvas.paste(Image.fromarray(np.repeat(colours, bar_width, axis=1), "RGB"), (left, top))
    for value, text in scale.ticks:
        y = top + (scale.vmax - value) / (scale.vmax - scale.vmin) * (bar_h - 1)
        draw.line([(left + bar_width, y), (left + bar_width + tick - 1, y)], fill=(235, 235, 235))
        draw.text((left + bar_width + tick + gap, y), text, fill=(235, 235, 235), font=font,
                  anchor="lm")
    return np.asarray(canvas)


def png_bytes(image: np.ndarray) -> bytes:
    """PNG encoding of a uint8 H x W x 3 image."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8), "RGB").save(buffer, format="PNG")
    return buffer.getvalue()


def write_previews(directory: str | Path, channels: Mapping[str, np.ndarray],
                   overwrite: bool = False) -> tuple[dict[str, Path], dict]:
    """Write all PNG previews of a render into ``directory``, each atomically.

    The analyser PNGs have the render's size; S1, S2, DoLP and AoLP carry a
    title and a colour bar (:func:`with_colour_bar`).

    Parameters
    ----------
    directory:
        An existing directory.
    channels:
        The output of :func:`polarization_channels`.
    overwrite:
        Replace existing preview files (otherwise :class:`FileExistsError`).

    Returns
    -------
    paths : dict
        Preview name (``I0``, ..., ``AoLP``, ``preview``) -> written path.
    settings : dict
        The display scales used (:func:`preview_settings`).
    """
    directory = Path(directory)
    settings = preview_settings(channels)
    previews = preview_images(channels, settings)
    for name, scale in colour_scales(settings).items():
        previews[name] = with_colour_bar(previews[name], scale)
    paths = {}
    for name, image in previews.items():
        paths[name] = atomic_write_bytes(directory / PREVIEW_FILES[name], png_bytes(image),
                                         overwrite=overwrite)
    labels = {f"{name}  ({name[1:]}\u00b0)": previews[name] for name in ANALYSER_CHANNELS}
    sheet = contact_sheet(labels)
    paths["preview"] = atomic_write_bytes(directory / CONTACT_SHEET_FILE, png_bytes(sheet),
                                          overwrite=overwrite)
    return paths, settings
