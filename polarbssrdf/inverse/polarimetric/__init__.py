"""The polarimetric stages: per-texel reflectance maps from polarization images (supplement sec. 5.1-5.2).

* :mod:`.model`: the pBRDF of :mod:`polarbssrdf.optics` evaluated per
  texel-view (the same functions the ``pbssrdf`` plugin calls);
* :mod:`.losses` (eq. 26-31) and :mod:`.regularizers` (eq. 33-35);
* :mod:`.patches`: texture patches with their texel-views and neighbourhoods;
* :mod:`.optimize`: the map parameters, their gradients and ``drjit.opt`` steps;
* :mod:`.fit`: epochs of patch steps with checkpoints, confidence, final maps;
* :mod:`.config`: the settings of both stages, the paper's by default;
* :mod:`.static` (sec. 5.1) and :mod:`.dynamic` (sec. 5.2, one pure function per frame).

Data flow: observations (:mod:`polarbssrdf.inverse.observations`) -> patches ->
model and losses -> optimizer -> fit -> static maps -> dynamic maps per frame,
written to the result directory (:mod:`polarbssrdf.inverse.results`), where the
biophysical stage reads their subsurface albedo.
"""
