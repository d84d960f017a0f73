"""The skin's other unknowns: what the chromophore fit and the band report hold, and how
uncertain they are.

Besides the four chromophores, the two-layer skin's band albedo (eq. 47) depends on the
epidermal thickness (mm), the blood's oxygen fraction ``gamma`` and the refractive index
``eta``. The biophysical fit holds them (docs/biophysical.md) and marginalizes them in its
std; the band report (:mod:`.band_information`) marginalizes them in its bound. Both read the
spreads here, so the two say the same thing about the same skin.
"""

from __future__ import annotations

import math

NUISANCES = ("thickness_mm", "gamma", "eta")
"""The skin's other unknowns: epidermal thickness (mm), the blood's oxygen fraction and the
refractive index."""

DEFAULT_NUISANCE_STD = {"thickness_mm": 0.018, "gamma": 0.02, "eta": 0.015}
"""Within-face spread of the nuisance maps. Thickness (mm): the spread between facial sites
that high-frequency ultrasound measures (site means 0.17-0.22 mm over eight sites, about
0.018 mm as a standard deviation; Meng et al., BMC Medical Imaging 22:113, 2022). It was a
guess at that spread's low end, 0.01 mm, until 2026-12-07: on the demo's first frame (synth
varies its faces by 0.025 mm) C_h_in's 2-std coverage was 0.879 with it and is 0.922 with
the measured spread; faces that vary less get a wider std than their error
(bench/RESULTS.md). Set ``nuisance_std`` where a capture's skin is known to vary otherwise.
Oxygenation: a stated guess (regions at rest differ by a few percent). Index: the static
stage's typical error (demo: MAE 0.013)."""

DEFAULT_NUISANCE_MEAN = {"thickness_mm": [0.25, 0.05], "gamma": [0.75, 0.08]}
"""``[mean, std]`` of a face's thickness (mm) and oxygenation: the skin model's values (Donner
and Jensen 2006; Donner et al. 2008) with the spread between people and sites."""


def nuisance_prior_std(name: str) -> float:
    """Prior standard deviation of one texel's value of nuisance ``name`` before the capture is
    seen: the face value's spread (:data:`DEFAULT_NUISANCE_MEAN`) and the spread within the
    face (:data:`DEFAULT_NUISANCE_STD`) in quadrature; the index has no face-value spread of
    its own here because it comes from the static stage with its error."""
    if name not in NUISANCES:
        raise ValueError(f"unknown nuisance {name!r}; known: {list(NUISANCES)}")
    face = DEFAULT_NUISANCE_MEAN.get(name, [None, 0.0])[1]
    return math.hypot(face, DEFAULT_NUISANCE_STD[name])


__all__ = ["NUISANCES", "DEFAULT_NUISANCE_STD", "DEFAULT_NUISANCE_MEAN", "nuisance_prior_std"]
