"""The HTML report of a result directory (``polarbssrdf report``).

:mod:`.page` reads a result and its capture and builds one self-contained
page; :mod:`.figures` draws its PNG figures (matplotlib); :mod:`.calibration`
measures how well posterior standard deviations cover the truth; :mod:`.commands` is
the command line. It sits above the acquisition: it reads the result
directory, the evaluation's scores and re-renders, and writes ``report.html``.
"""
