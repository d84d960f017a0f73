"""PNG previews of result maps, each with a colour bar and its unit."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from polarbssrdf.inverse.results.directory import RESULT_UNITS
from polarbssrdf.io.atomic import atomic_write_bytes

MAP_RANGES = {"eta": (1.3, 1.6), "alpha_s": (0.1, 0.7), "alpha_ss": (0.7, 1.0),
              "confidence": (0.0, 1.0), "specular_peak_angle": (0.0, 90.0)}
"""Fixed colour ranges where the parameter has natural bounds; others use the 1st-99th percentile."""


def _unit(name, units=None):
    parameter = name.partition(".")[0]
    unit = (units or RESULT_UNITS).get(parameter, "1")
    return "dimensionless" if unit == "1" else unit


def _range(name, values):
    if name in MAP_RANGES:
        return MAP_RANGES[name]
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return 0.0, 1.0
    low, high = np.percentile(finite, [1, 99])
    if name.startswith("displacement"):
        bound = max(abs(low), abs(high), 1e-6)
        return -bound, bound
    return float(low), float(max(high, low + 1e-6))


def map_preview_png(name, values, units=None):
    """PNG bytes of one map with a colour bar labelled with its unit (``units``: name -> unit,
    default the result maps' units)."""
    values = np.asarray(values, np.float32)
    low, high = _range(name, values)
    cmap = "coolwarm" if name.startswith("displacement") else "viridis"
    # matplotlib's object interface on an Agg canvas: no pyplot state, and the caller's
    # backend (a notebook's, say) is left alone
    figure = Figure(figsize=(3.6, 3.0), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.subplots()
    if name.startswith("normal"):
        image = axes.imshow(values, vmin=-1, vmax=1, cmap="coolwarm", interpolation="nearest")
    else:
        image = axes.imshow(values, vmin=low, vmax=high, cmap=cmap, interpolation="nearest")
    axes.set_title(name, fontsize=9)
    axes.set_xticks([])
    axes.set_yticks([])
    bar = figure.colorbar(image, ax=axes, fraction=0.046, pad=0.04)
    bar.set_label(_unit(name, units), fontsize=8)
    bar.ax.tick_params(labelsize=7)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", bbox_inches="tight")
    return buffer.getvalue()


def normal_map_png(maps):
    """PNG bytes of the normals as RGB ``(n + 1) / 2``."""

    normal = np.stack([maps["normal.x"], maps["normal.y"], maps["normal.z"]], axis=-1)
    rgb = np.clip((normal + 1.0) * 0.5 * 255.0 + 0.5, 0, 255).astype(np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG")
    return buffer.getvalue()


def write_map_previews(maps, directory, suffix, units=None):
    """``<directory>/<map>_<suffix>.png`` for every map (atomic writes); returns the paths."""

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, values in maps.items():
        if name.startswith("normal."):
            continue
        path = directory / f"{name}_{suffix}.png"
        atomic_write_bytes(path, map_preview_png(name, values, units), overwrite=True)
        paths.append(path)
    if all(f"normal.{axis}" in maps for axis in "xyz"):
        path = directory / f"normal_{suffix}.png"
        atomic_write_bytes(path, normal_map_png(maps), overwrite=True)
        paths.append(path)
    return paths
