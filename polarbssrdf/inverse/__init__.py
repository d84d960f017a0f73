"""The acquisition: from a capture to per-texel maps (supplement sec. 5 and 6).

Data flows one way, a folder per stage of the paper, each reading the one
before from disk::

    capture (polarbssrdf.io)
      -> observations/   texel-view samples of every image, a chunked zarr store (sec. 5.1 inputs)
      -> polarimetric/   the per-texel-view pBRDF model, losses, optimizer; the static stage
                         (sec. 5.1) and the dynamic stage per frame (sec. 5.2)
      -> biophysical/    melanin and hemoglobin from the subsurface albedo (sec. 5.3)
      -> results/        the result directory every stage writes and reads, previews
      -> evaluation/     scores against truth and held-out re-renders (sec. 6)
      -> polarbssrdf.report: the HTML report

``results/`` and ``observations/`` sit at the bottom: every stage uses them,
they use no stage. ``frames.py`` runs independent frames serially or on Dask;
``config.py`` reads a run's configuration (each stage checks its own part);
``pipeline.py`` runs the stages in order (:func:`reconstruct`, :func:`evaluate`);
``commands.py`` is the command line over it.

From Python::

    from polarbssrdf.inverse import reconstruct
    result = reconstruct("capture", "result", holdout=("cam03",))
    result.maps("bio", 0)["C_h_out"]
"""

import importlib

__all__ = ["Reconstruction", "ResultDirectory", "evaluate", "reconstruct"]

_LAZY = {
    "reconstruct": "polarbssrdf.inverse.pipeline",
    "evaluate": "polarbssrdf.inverse.pipeline",
    "Reconstruction": "polarbssrdf.inverse.pipeline",
    "ResultDirectory": "polarbssrdf.inverse.results.directory",
}


def __getattr__(name):
    # The pipeline imports every stage; importing this package (as the command line does
    # for its argument parser) must not, so the API is resolved on first use (PEP 562).
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
