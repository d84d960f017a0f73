"""The figures of the HTML report (:mod:`polarbssrdf.report.page`), each as PNG bytes.

Every function draws one figure with matplotlib's object interface
(:class:`matplotlib.figure.Figure` on an Agg canvas, no ``pyplot`` state), so
figures can be made from any thread or worker. Maps are ``(T, T)`` arrays in
the package's texture convention (row 0 at the top); texels outside ``mask``
are drawn as background.
"""

from __future__ import annotations

import io
import textwrap

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure

from polarbssrdf.report.calibration import COVERAGE_K, expected_coverage

DPI = 100
MAP_PANEL_INCHES = 2.7
BACKGROUND = "#e8e8e8"
"""Colour of texels that are not on the mesh (or were not scored)."""
UNITLESS = "unitless"
"""Colour bar label of dimensionless maps (a bare "1" reads as a stray digit)."""
RADIANCE_UNIT = r"radiance [W sr$^{-1}$ mm$^{-2}$]"
"""Colour bar label of captured and re-rendered images: radiance in the capture's units
(intensity W/sr over mm^2, ``polarbssrdf.io.manifest.CAPTURE_UNITS``)."""


def _figure(width, height):

    figure = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def _png(figure) -> bytes:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=DPI)
    return buffer.getvalue()


def _masked(values, mask):
    values = np.asarray(values, dtype=np.float64)
    return np.ma.masked_where(~(np.asarray(mask, bool) & np.isfinite(values)), values)


def _robust_range(*arrays, percentile=1.0):
    """Low and high percentiles over the unmasked values of ``arrays`` (never equal)."""
    values = np.concatenate([np.ma.compressed(a) for a in arrays if np.ma.count(a)] or
                            [np.zeros(1)])
    low, high = np.percentile(values, [percentile, 100.0 - percentile])
    if not high > low:
        spread = max(abs(low) * 0.01, 1e-6)
        low, high = low - spread, high + spread
    return float(low), float(high)


def unit_label(unit) -> str:
    """Colour bar label of a map in ``unit``: dimensionless units ("1", "") read "unitless"."""
    text = "" if unit is None else str(unit).strip()
    return UNITLESS if text in ("", "1") else text


def _map_axes(axes, values, title, vmin, vmax, cmap, unit, figure):

    colormap = matplotlib.colormaps[cmap].with_extremes(bad=BACKGROUND)
    image = axes.imshow(values, vmin=vmin, vmax=vmax, cmap=colormap, interpolation="antialiased")
    axes.set_title(title, fontsize=9)
    axes.set_xticks([])
    axes.set_yticks([])
    bar = figure.colorbar(image, ax=axes, fraction=0.046, pad=0.03)
    bar.set_label(unit_label(unit), fontsize=8)
    bar.ax.tick_params(labelsize=7)


Z_LIMIT = 3.0
"""The z-score panel's colour scale runs from -3 to 3 std: a calibrated posterior leaves
0.3% of the texels beyond it (saturated), 4.6% beyond 2."""


def map_comparison_png(name, recovered, truth, mask, unit="1", relative=False,
                       std=None, note=None) -> bytes:
    """:func:`map_comparison_figure` as PNG bytes."""
    return _png(map_comparison_figure(name, recovered, truth, mask, unit, relative, std, note))


def map_comparison_figure(name, recovered, truth, mask, unit="1", relative=False,
                          std=None, note=None):
    """One map: recovered | truth (one colour scale) | error [| posterior std [| error / std]],
    with colour bars and units (a :class:`~matplotlib.figure.Figure`).

    Parameters
    ----------
    name : str
        Channel name (the title).
    recovered, truth : (T, T) arrays
        The result's map and the ground truth; ``truth`` may be None (a real
        capture): then no truth and no error panel are drawn.
    mask : (T, T) bool
        Texels shown (and scored): on the mesh, confident, finite truth.
    unit : str
        Unit of the map, on its colour bar ("1": "unitless").
    relative : bool
        Draw the error as ``(recovered - truth) / truth`` in percent (albedos)
        rather than as a difference in ``unit``.
    std : (T, T) array, optional
        The map's posterior standard deviation (same unit), drawn on its own
        scale from 0; with ``truth`` also the z-score ``(recovered - truth) / std``
        (unitless, -3 to 3: a calibrated std leaves 95% of the texels within +-2).
    note : str, optional
        A line under the panels (e.g. that the map was held at its face mean).
    """
    estimate = _masked(recovered, mask)
    with_z = std is not None and truth is not None
    columns = (1 if truth is None else 3) + (std is not None) + with_z
    figure = _figure(MAP_PANEL_INCHES * (1.15 if columns == 1 else 1.1 * columns),
                     MAP_PANEL_INCHES + (0.3 if note else 0.0))
    panels = list(np.atleast_1d(figure.subplots(1, columns)))
    if truth is None:
        low, high = _robust_range(estimate)
        _map_axes(panels.pop(0), estimate, f"{name} (recovered)", low, high, "viridis", unit,
                  figure)
    else:
        reference = _masked(truth, mask)
        low, high = _robust_range(estimate, reference)
        if relative:
            error = 100.0 * (estimate - reference) / np.ma.masked_less_equal(reference, 0.0)
            error_unit = "% of truth"
        else:
            error = estimate - reference
            error_unit = unit
        limit = (float(np.percentile(np.abs(np.ma.compressed(error)), 99))
                 if np.ma.count(error) else 1)
        limit = limit if limit > 0 else 1e-6
        _map_axes(panels.pop(0), estimate, f"{name}: recovered", low, high, "viridis", unit,
                  figure)
        _map_axes(panels.pop(0), reference, f"{name}: truth", low, high, "viridis", unit,
                  figure)
        _map_axes(panels.pop(0), error, "error (recovered - truth)", -limit, limit, "RdBu_r",
                  error_unit, figure)
    if std is not None:
        spread = _masked(std, mask)
        high = (float(np.percentile(np.ma.compressed(spread), 99)) if np.ma.count(spread)
                else 0.0)
        _map_axes(panels.pop(0), spread, f"{name}: posterior std", 0.0,
                  high if high > 0 else 1e-6, "magma", unit, figure)
    if with_z:
        z = (_masked(recovered, mask) - _masked(truth, mask)) / np.ma.masked_less_equal(
            _masked(std, mask), 0.0)
        within = float(np.mean(np.abs(np.ma.compressed(z)) < 2.0)) if np.ma.count(z) else \
            float("nan")
        _map_axes(panels.pop(0), z, f"error / std: {100 * within:.0f}% within 2 (ideal 95%)",
                  -Z_LIMIT, Z_LIMIT, "RdBu_r", "z-score (error / posterior std)", figure)
    if note:
        figure.suptitle(note, fontsize=8, color="#b00", y=0.02, va="bottom")
    return figure


def normal_rgb(normal, mask):
    """``(T, T, 3)`` RGB image ``(n + 1) / 2`` of unit normals, background outside ``mask``."""

    rgb = np.clip((np.asarray(normal, np.float64) + 1.0) * 0.5, 0.0, 1.0)
    rgb[~np.asarray(mask, bool)] = to_rgb(BACKGROUND)
    return rgb


def normals_png(recovered, truth, mask) -> bytes:
    """Normal maps as RGB ``(n + 1) / 2`` (object space): recovered | truth | angle between them.

    ``recovered``, ``truth``: ``(T, T, 3)`` unit normals (``truth`` may be None).
    """
    columns = 1 if truth is None else 3
    figure = _figure(MAP_PANEL_INCHES * (1.0 if columns == 1 else 3.2), MAP_PANEL_INCHES)
    panels = np.atleast_1d(figure.subplots(1, columns))
    panels[0].imshow(normal_rgb(recovered, mask), interpolation="antialiased")
    panels[0].set_title("normals: recovered (RGB = (n + 1) / 2)", fontsize=9)
    if truth is not None:
        panels[1].imshow(normal_rgb(truth, mask), interpolation="antialiased")
        panels[1].set_title("normals: truth", fontsize=9)
        cosine = np.clip(np.sum(np.asarray(recovered) * np.asarray(truth), axis=-1), -1.0, 1.0)
        angle = _masked(np.degrees(np.arccos(cosine)), mask)
        high = max(float(np.percentile(np.ma.compressed(angle), 99)) if np.ma.count(angle)
                   else 1.0, 1e-3)
        _map_axes(panels[2], angle, "angle between them", 0.0, high, "magma", "degrees",
                  figure)
    for axes in panels[:2]:
        axes.set_xticks([])
        axes.set_yticks([])
    return _png(figure)


def input_views_png(views, unit=RADIANCE_UNIT) -> bytes:
    """The capture's I0 and I90 images: one column per view, I0 above I90.

    ``views``: list of ``(title, I0, I90)`` with 2-D arrays of one band (the
    title says whether the view was held out of the fit). Both images of a
    view share one linear scale (0 to the 99.5th percentile of I0), so the
    specular light that I90 blocks shows as the difference.
    """
    columns = len(views)
    figure = _figure(3.1 * columns, 5.6)
    panels = figure.subplots(2, columns, squeeze=False)
    for column, (title, i0, i90) in enumerate(views):
        finite = i0[np.isfinite(i0)]
        high = (float(np.percentile(finite, 99.5)) if finite.size else 0.0) or 1.0
        for row, (label, image) in enumerate((("I0", i0), ("I90", i90))):
            _map_axes(panels[row, column], np.ma.masked_invalid(image), f"{title}: {label}",
                      0.0, high, "gray", unit, figure)
    return _png(figure)


def changes_over_frames_png(name, recovered, truth, mask, unit="1") -> bytes:
    """``name`` at each frame minus its value at the first frame: recovered row over truth row.

    ``recovered``, ``truth``: ``{frame: (T, T) array}`` (``truth`` may be None).
    """
    frames = sorted(recovered)[1:]
    if not frames:
        raise ValueError("a change over frames needs at least two frames")
    first = min(recovered)
    rows = [("recovered", recovered)] + ([("truth", truth)] if truth is not None else [])
    changes = {(label, f): _masked(np.asarray(maps[f]) - np.asarray(maps[first]), mask)
               for label, maps in rows for f in frames}
    limit = max(float(np.percentile(np.abs(np.ma.compressed(c)), 99.5)) if np.ma.count(c) else 0
                for c in changes.values()) or 1e-6
    figure = _figure(min(2.6 * len(frames), 13.0) + 0.8, 2.5 * len(rows))
    panels = figure.subplots(len(rows), len(frames), squeeze=False)

    colormap = matplotlib.colormaps["RdBu_r"].with_extremes(bad=BACKGROUND)
    image = None
    for r, (label, _) in enumerate(rows):
        for c, frame in enumerate(frames):
            axes = panels[r, c]
            image = axes.imshow(changes[label, frame], vmin=-limit, vmax=limit, cmap=colormap,
                                interpolation="antialiased")
            axes.set_title(f"{label}, frame {frame}", fontsize=9)
            axes.set_xticks([])
            axes.set_yticks([])
    bar = figure.colorbar(image, ax=panels, fraction=0.03, pad=0.02)
    bar.set_label(f"{name} minus frame {first} [{unit_label(unit)}]", fontsize=8)
    return _png(figure)


def region_series_png(parameters, recovered, truth, units, notes=None) -> bytes:
    """Mean of each parameter per region over the frames: recovered (solid) and truth (dashed).

    ``notes``: ``{parameter: text}`` shown under a panel's title (e.g. that the map was
    held at its face mean or is prior-dominated).

    ``recovered``, ``truth``: a region summary
    (:func:`polarbssrdf.inverse.biophysical.stage.region_summary`) each; ``truth`` may be None.
    The left and right cheeks are drawn as ``cheeks`` when the summary has it.
    """

    regions = [r for r in recovered["regions"]
               if not (r.startswith("cheek_") and "cheeks" in recovered["regions"])]
    colours = matplotlib.colormaps["tab10"]
    figure = _figure(4.2 * len(parameters), 3.2)
    panels = np.atleast_1d(figure.subplots(1, len(parameters)))
    frames = []
    for axes, parameter in zip(panels, parameters):
        for index, region in enumerate(regions):
            colour = colours(index % 10)
            series = recovered["regions"][region]["frames"]
            frames = sorted(int(f) for f in series)
            mean = [series[str(f)][parameter]["mean"] for f in frames]
            axes.plot(frames, mean, "o-", color=colour, label=region, lw=1.6, ms=4)
            if truth is not None and region in truth["regions"]:
                reference = truth["regions"][region]["frames"]
                known = [f for f in frames if str(f) in reference]
                axes.plot(known, [reference[str(f)][parameter]["mean"] for f in known], "--",
                          color=colour, lw=1.2)
        axes.set_xlabel("frame")
        axes.set_ylabel(f"{parameter} [{unit_label(units.get(parameter))}]")
        axes.set_title(f"{parameter}, region mean" + (" (solid: recovered, dashed: truth)"
                                                      if truth is not None else ""),
                       fontsize=9)
        if notes and notes.get(parameter):
            axes.text(0.02, 0.98, textwrap.fill(notes[parameter], 48),
                      transform=axes.transAxes, ha="left", va="top", fontsize=7,
                      color="#b00", bbox=dict(facecolor="white", alpha=0.85, edgecolor="none"))
        axes.grid(alpha=0.3)
        if 1 < len(frames) <= 20:
            axes.set_xticks(frames)
    panels[0].legend(fontsize=7)
    return _png(figure)


def _loss_axes(axes, xlabel, ylabel, title, legend=None):
    """Log-scale loss axes whose legend sits below the plot, never over the curves."""
    axes.set_yscale("log")
    axes.set_xlabel(xlabel)
    axes.set_ylabel(ylabel)
    axes.set_title(title, fontsize=10)
    options = {"fontsize": 7, "ncol": 2, **(legend or {})}
    axes.legend(loc="upper center", bbox_to_anchor=(0.5, -0.22), frameon=False, **options)
    axes.grid(alpha=0.3)


def loss_curves_png(static_history, dynamic_histories, bio_histories) -> bytes:
    """Loss per epoch (static: every term; dynamic: total per frame) and per
    Gauss-Newton iteration (biophysical: per frame); log scale (:func:`loss_curves_figure`)."""
    return _png(loss_curves_figure(static_history, dynamic_histories, bio_histories))


def loss_curves_figure(static_history, dynamic_histories, bio_histories):
    """The :class:`~matplotlib.figure.Figure` of :func:`loss_curves_png` (legends below the
    axes)."""

    panels_wanted = [p for p, present in (("static", static_history),
                                          ("dynamic", dynamic_histories),
                                          ("bio", bio_histories)) if present]
    if not panels_wanted:
        raise ValueError("no loss history to plot")
    figure = _figure(4.3 * len(panels_wanted), 4.6)
    panels = dict(zip(panels_wanted, np.atleast_1d(figure.subplots(1, len(panels_wanted)))))
    colours = matplotlib.colormaps["viridis"]
    if static_history:
        axes = panels["static"]
        epochs = [entry.get("epoch", i + 1) for i, entry in enumerate(static_history)]
        skip = {"epoch", "gradient_norm", "skipped", "photometric_noise"}
        terms = [k for k in static_history[0] if k not in skip]
        for term in terms:
            values = np.array([entry.get(term, np.nan) for entry in static_history], float)
            if not np.any(values > 0):
                continue
            style = dict(lw=2.2, color="black") if term == "total" else dict(lw=1.1)
            axes.plot(epochs, values, label=term, **style)
        _loss_axes(axes, "epoch", "loss (chi-square per texel-view; weighted)", "static stage",
                   legend=dict(fontsize=6, ncol=3))
    if dynamic_histories:
        axes = panels["dynamic"]
        frames = sorted(dynamic_histories, key=int)
        for index, frame in enumerate(frames):
            history = dynamic_histories[frame]
            axes.plot([e.get("epoch", i + 1) for i, e in enumerate(history)],
                      [e.get("total", np.nan) for e in history],
                      color=colours(index / max(len(frames) - 1, 1)), label=f"frame {frame}")
        _loss_axes(axes, "epoch", "total loss", "dynamic stage")
    if bio_histories:
        axes = panels["bio"]
        frames = sorted(bio_histories, key=int)
        for index, frame in enumerate(frames):
            losses = [v for entry in bio_histories[frame] for v in entry.get("losses", [])]
            axes.plot(np.arange(len(losses)), losses, "o-", ms=2.5,
                      color=colours(index / max(len(frames) - 1, 1)), label=f"frame {frame}")
        _loss_axes(axes, "Gauss-Newton iteration", "loss (data + prior)", "biophysical stage")
    return figure


def rerender_png(camera, band, observed, rendered, mask, unit=RADIANCE_UNIT) -> bytes:
    """A view of the capture beside its re-render with the recovered maps:
    I_sss = 2 I90 and I_s = I0 - I90 observed | re-rendered | residual."""
    figure = _figure(9.6, 5.2)
    panels = figure.subplots(2, 3)
    for row, (label, part) in enumerate((("I_sss", lambda v: 2.0 * v["I90"]),
                                         ("I_s", lambda v: v["I0"] - v["I90"]))):
        seen = _masked(part(observed), mask)
        model = _masked(part(rendered), mask)
        low, high = _robust_range(seen, model, percentile=0.5)
        residual = model - seen
        limit = float(np.percentile(np.abs(np.ma.compressed(residual)), 99)) \
            if np.ma.count(residual) else 1.0
        _map_axes(panels[row, 0], seen, f"{camera} {band}: {label} captured", low, high, "gray",
                  unit, figure)
        _map_axes(panels[row, 1], model, f"{label} re-rendered", low, high, "gray", unit, figure)
        _map_axes(panels[row, 2], residual, "re-rendered - captured", -limit or -1e-6,
                  limit or 1e-6, "RdBu_r", unit, figure)
    return _png(figure)


def calibration_png(curves, ks=COVERAGE_K, notes=None, markers=None) -> bytes:
    """:func:`calibration_figure` as PNG bytes."""
    return _png(calibration_figure(curves, ks, notes, markers))


def calibration_figure(curves, ks=COVERAGE_K, notes=None, markers=None):
    """Observed coverage of the posterior std against k, one line per map, beside
    the coverage a calibrated Gaussian std gives, ``erf(k / sqrt 2)`` (dashed).

    ``curves``: ``{name: (fractions, texels)}`` of :func:`coverage_fractions`;
    ``notes``: ``{name: text}`` added to a map's legend entry (e.g. "held at
    its face mean"); ``markers``: ``{name: matplotlib marker}`` (default a circle), e.g.
    one per stage. The horizontal axis is k itself, to a little beyond the largest k
    (3), so the points at 2-3 std, where a calibrated std covers 95-99.7%, are spread
    out instead of crowded against 1. Points above the dashed curve: the std is too
    large (errors smaller than claimed); below: too small (overconfident).
    """
    ks = np.asarray(ks, float)
    columns = 1 if len(curves) <= 8 else 2
    figure = _figure(5.8 if columns == 1 else 7.6, 4.4 + 0.16 * (len(curves) // columns + 2))
    axes = figure.add_subplot(1, 1, 1)
    fine = np.linspace(0.0, ks[-1] + 0.25, 200)
    axes.plot(fine, expected_coverage(fine), color="0.35", lw=1.2, ls="--",
              label="calibrated: erf(k / sqrt 2)")
    ideal = float(expected_coverage((2.0,))[0])
    axes.axvline(2.0, color="0.6", lw=0.8, ls=":")
    axes.text(2.03, 0.02, f"k = 2: ideal {ideal:.3f}", fontsize=7, color="0.3")
    colours = matplotlib.colormaps["tab10" if len(curves) <= 10 else "tab20"]
    for index, (name, (fractions, texels)) in enumerate(curves.items()):
        extra = f", {notes[name]}" if notes and notes.get(name) else ""
        marker = (markers or {}).get(name, "o")
        axes.plot(ks, fractions, marker=marker, ls="-", ms=3.5, lw=1.4,
                  color=colours(index % colours.N),
                  label=f"{name} ({texels:,} texels{extra})")
    axes.set_xlim(0.0, ks[-1] + 0.25)
    axes.set_ylim(0.0, 1.04)
    axes.set_xticks(np.arange(0.0, ks[-1] + 0.01, 0.5))
    axes.set_xlabel(f"k (multiples of the posterior std), {ks[0]:g} to {ks[-1]:g}")
    axes.set_ylabel("fraction of texels with |recovered - truth| < k std")
    axes.set_title("posterior calibration", fontsize=10)
    axes.grid(alpha=0.3)
    # below the axes, never over the curves (their low ends sit in the lower right)
    axes.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False,
                ncol=columns)
    return figure


def transfer_png(curve) -> bytes:
    """:func:`transfer_figure` as PNG bytes."""
    return _png(transfer_figure(curve))


def transfer_figure(curve):
    """The displacement's transfer curve: gain and correlation against the truth per octave
    band of spatial scale (``evaluate``'s ``displacement.transfer``, finest first), the
    band drawn at the geometric mean of its Gaussian scales (the finest at half a texel)."""
    figure = _figure(5.8, 3.6)
    axes = figure.add_subplot(1, 1, 1)
    centres = [np.sqrt(low * high) if low > 0 else 0.5 * high
               for low, high in (band["sigma_mm"] for band in curve)]
    axes.axhline(1.0, color="0.6", lw=0.8, ls=":")
    axes.plot(centres, [band["gain"] for band in curve], "o-", color="C0",
              label="gain (recovered / true amplitude)")
    axes.plot(centres, [band["correlation"] for band in curve], "s--", color="C1",
              label="correlation with the truth")
    axes.set_xscale("log")
    axes.set_xticks(centres)
    axes.set_xticklabels([f"{c:.2g}" for c in centres])
    axes.set_xlabel("spatial scale (Gaussian sigma of the band, mm)")
    axes.set_ylabel("unitless")
    axes.set_ylim(min(0.0, *(band["gain"] for band in curve)) - 0.05,
                  max(1.2, *(band["gain"] for band in curve)) + 0.05)
    axes.set_title("displacement: which scales of the relief are recovered", fontsize=10)
    axes.grid(alpha=0.3)
    axes.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False, ncol=2)
    return figure
