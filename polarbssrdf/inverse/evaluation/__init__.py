"""Evaluation of a result (supplement sec. 6): scores against truth and held-out re-renders.

* :mod:`.scores`: every stage's maps against a synthetic capture's truth maps,
  each figure next to the best constant map's;
* :mod:`.rerender`: a camera re-rendered in Mitsuba with the ``pbssrdf``
  plugin, the recovered maps and the displaced mesh, compared with the
  captured images (the held-out cameras of a run);
* :mod:`.trust`: whether the maps and the posterior std can be trusted, from the run's own
  data (usable views per confident texel against what the per-texel model needs).

Data flow: the result directory (:mod:`polarbssrdf.inverse.results`) and the
capture -> scores and residuals (``evaluate``'s JSON, the report).
"""
