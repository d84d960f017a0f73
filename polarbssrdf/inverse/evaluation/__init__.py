"""Evaluation of a result (supplement sec. 6): scores against truth and held-out re-renders.

* :mod:`.scores`: every stage's maps against a synthetic capture's truth maps,
  each figure next to the best constant map's;
* :mod:`.rerender`: a camera re-rendered in Mitsuba with the ``pbssrdf``
  plugin, the recovered maps and the displaced mesh, compared with the
  captured images (the held-out cameras of a run).

Data flow: the result directory (:mod:`polarbssrdf.inverse.results`) and the
capture -> scores and residuals (``evaluate``'s JSON, the report).
"""
