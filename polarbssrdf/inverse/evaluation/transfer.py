"""Which scales of the face's relief a capture resolves: the displacement's transfer curve.

A displacement map's error says how far it is from the truth, not at which scales it
holds the truth's detail. :func:`displacement_transfer` splits both maps into octave
bands of spatial scale (differences of Gaussian low-passes, masked so that texels off
the mesh or not confident do not leak in) and, per band, regresses the recovered band
on the truth's: a gain of 1 carries the truth's relief at that scale, 0 flattens it,
and the correlation says how much of the band is the truth's rather than noise. It is
the empirical counterpart of a modulation transfer function (ISO 12233's, for
cameras), measured against the truth rather than a test chart.
"""

from __future__ import annotations

import numpy as np

from polarbssrdf._arrays import masked_low_pass

OCTAVES = 5
"""Bands of Gaussian scale ``[0, 1], [1, 2], [2, 4], [4, 8], [8, 16]`` texels."""


def displacement_transfer(recovered, truth, mask, texel_mm, octaves=OCTAVES):
    """Per octave band of spatial scale, how much of the truth's displacement the result holds.

    Parameters
    ----------
    recovered, truth : (T, T) arrays
        Displacement maps, mm.
    mask : (T, T) bool
        Texels scored (on the mesh, confident).
    texel_mm : float
        The texel's size, mm (for the bands' scales in mm).

    Returns
    -------
    list of dict
        Per band, finest first: ``sigma_mm`` ``[low, high]`` (the Gaussian scales whose
        difference is the band), ``gain`` (regression slope of the recovered band on the
        truth's), ``correlation``, ``truth_rms_mm`` and ``error_rms_mm`` of the band.
    """
    mask = np.asarray(mask, bool)
    out = []
    edges = [0.0] + [2.0 ** k for k in range(octaves)]
    for low, high in zip(edges[:-1], edges[1:]):
        bands = []
        for values in (recovered, truth):
            band = masked_low_pass(values, mask, low) - masked_low_pass(values, mask, high)
            bands.append(band[mask])
        estimate, reference = bands
        power = float(np.sum(reference * reference))
        gain = float(np.sum(estimate * reference) / power) if power > 0 else float("nan")
        spread = float(np.std(estimate) * np.std(reference))
        correlation = (float(np.mean((estimate - estimate.mean()) * (reference - reference.mean())) / spread)
                       if spread > 0 else float("nan"))
        out.append({"sigma_mm": [round(low * texel_mm, 4), round(high * texel_mm, 4)],
                    "gain": gain, "correlation": correlation,
                    "truth_rms_mm": float(np.sqrt(np.mean(reference ** 2))),
                    "error_rms_mm": float(np.sqrt(np.mean((estimate - reference) ** 2)))})
    return out
