"""Filter layouts of division-of-focal-plane polarization sensors.

A layout is one period of the sensor's filter pattern: for every pixel of the
period, the angle of its linear analyser (degrees, counter-clockwise from image
right, as in :mod:`polarbssrdf.optics.stokes`) and the name of its colour
filter. Row 0 of a pattern is the top row of the image (the first row read
out), column 0 its left column.

Sony's IMX250MZR (monochrome) has 2 x 2 polarizer cells with 90/45 on the top
row and 135/0 on the bottom row; the IMX250MYR (colour) puts each such cell
under one colour filter and arranges the cells in an RGGB Bayer pattern, so its
period is 4 x 4 (the pattern used by Morimatsu et al., "Monochrome and color
polarization demosaicking using edge-aware residual interpolation", ICIP 2020).

Analyser images are named ``I<angle>`` with a colour suffix ``.<colour>`` for
colour layouts (``I0.R``, ``I45.G``, ...), the channel names that
:func:`polarbssrdf.render.stokes_images.analyser_images` writes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polarbssrdf.optics.stokes import ANALYSER_ANGLES_DEG

__all__ = ["IMX250MYR", "IMX250MZR", "SensorLayout", "channel_name"]


def channel_name(angle_deg: int, colour: str = "") -> str:
    """Name of an analyser image: ``I<angle>`` plus ``.<colour>`` when ``colour`` is not empty.

    Parameters
    ----------
    angle_deg:
        Analyser angle in degrees (one of 0, 45, 90, 135).
    colour:
        Colour filter name; ``""`` for a monochrome sensor.
    """
    return f"I{angle_deg}" + (f".{colour}" if colour else "")


@dataclass(frozen=True)
class SensorLayout:
    """One period of a polarization (and colour) filter array.

    Parameters
    ----------
    name:
        A label, e.g. the sensor's part number.
    angles_deg:
        Rows of analyser angles in degrees, one entry per pixel of the period,
        top row first. Every angle must be one of 0, 45, 90, 135.
    colours:
        Rows of colour filter names with the same shape as ``angles_deg``;
        ``""`` everywhere for a monochrome sensor.
    """

    name: str
    angles_deg: tuple[tuple[int, ...], ...]
    colours: tuple[tuple[str, ...], ...]

    def __post_init__(self) -> None:
        angles = np.asarray(self.angles_deg)
        colours = np.asarray(self.colours, dtype=object)
        if angles.ndim != 2 or angles.size == 0:
            raise ValueError(f"layout {self.name!r}: angles_deg must be a non-empty rectangular "
                             f"table of rows, got {self.angles_deg!r}")
        if colours.shape != angles.shape:
            raise ValueError(f"layout {self.name!r}: colours has shape {colours.shape} but "
                             f"angles_deg has shape {angles.shape}")
        unknown = sorted(set(angles.ravel().tolist()) - set(ANALYSER_ANGLES_DEG))
        if unknown:
            raise ValueError(f"layout {self.name!r}: analyser angles {unknown} are not among "
                             f"{ANALYSER_ANGLES_DEG}")
        if not all(isinstance(c, str) for c in colours.ravel()):
            raise ValueError(f"layout {self.name!r}: colour names must be strings")
        names = set(colours.ravel().tolist())
        if "" in names and len(names) > 1:
            raise ValueError(f"layout {self.name!r}: mixes unfiltered ('') and colour pixels")
        for colour in names:
            present = set(angles[colours == colour].tolist())
            if present != set(ANALYSER_ANGLES_DEG):
                missing = sorted(set(ANALYSER_ANGLES_DEG) - present)
                raise ValueError(f"layout {self.name!r}: colour {colour!r} has no pixels with "
                                 f"analyser angles {missing}")

    @property
    def period(self) -> tuple[int, int]:
        """``(rows, columns)`` of one period of the pattern, in pixels."""
        return len(self.angles_deg), len(self.angles_deg[0])

    @property
    def colour_names(self) -> tuple[str, ...]:
        """Colour filter names in order of first appearance (row-major); ``("",)`` if monochrome."""
        seen: dict[str, None] = {}
        for row in self.colours:
            for colour in row:
                seen.setdefault(colour, None)
        return tuple(seen)

    @property
    def is_colour(self) -> bool:
        return self.colour_names != ("",)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """All analyser image names, angle first then colour: ``I0.R, I0.G, I0.B, I45.R, ...``."""
        return tuple(channel_name(a, c) for a in ANALYSER_ANGLES_DEG for c in self.colour_names)

    def offsets(self, angle_deg: int, colour: str = "") -> tuple[tuple[int, int], ...]:
        """``(row, column)`` positions, inside one period, of this analyser and colour."""
        return tuple((r, c) for r, row in enumerate(self.angles_deg) for c, a in enumerate(row)
                     if a == angle_deg and self.colours[r][c] == colour)

    def check_shape(self, shape: tuple[int, ...], what: str = "image") -> tuple[int, int]:
        """Return ``(H, W)`` of a 2-D ``shape`` whose sides are multiples of the period.

        Raises
        ------
        ValueError
            If ``shape`` is not 2-D, is empty, or a side is not a multiple of the period.
        """
        if len(shape) != 2:
            raise ValueError(f"{what} must be a 2-D H x W array, got shape {tuple(shape)}")
        rows, cols = self.period
        height, width = shape
        if height == 0 or width == 0:
            raise ValueError(f"{what} is empty (shape {tuple(shape)})")
        if height % rows or width % cols:
            raise ValueError(f"{what} size {height} x {width} is not a multiple of the "
                             f"{rows} x {cols} period of layout {self.name!r}")
        return height, width

    def sample_mask(self, shape: tuple[int, int], angle_deg: int, colour: str = "") -> np.ndarray:
        """Boolean H x W mask of the pixels that sample ``channel_name(angle_deg, colour)``."""
        height, width = self.check_shape(shape)
        rows, cols = self.period
        cell = np.zeros(self.period, dtype=bool)
        for r, c in self.offsets(angle_deg, colour):
            cell[r, c] = True
        return np.tile(cell, (height // rows, width // cols))


IMX250MZR = SensorLayout(
    name="IMX250MZR",
    angles_deg=((90, 45),
                (135, 0)),
    colours=(("", ""),
             ("", "")),
)
"""Sony IMX250MZR: monochrome, 2 x 2 cells of 90/45 over 135/0."""

IMX250MYR = SensorLayout(
    name="IMX250MYR",
    angles_deg=((90, 45, 90, 45),
                (135, 0, 135, 0),
                (90, 45, 90, 45),
                (135, 0, 135, 0)),
    colours=(("R", "R", "G", "G"),
             ("R", "R", "G", "G"),
             ("G", "G", "B", "B"),
             ("G", "G", "B", "B")),
)
"""Sony IMX250MYR: the IMX250MZR cells under an RGGB Bayer pattern of cells (4 x 4 period)."""
