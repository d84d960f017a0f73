"""Texture-space observations: the inputs of the polarimetric stages (supplement sec. 5.1).

For one frame of a capture and a texel atlas of its mesh, :mod:`.build` turns
every image into *texel-views* (a texel seen by a camera under a light: its
object-space geometry and the four analyser samples per band, raw mosaics
demosaicked and converted to radiance first), with visibility by Mitsuba ray
casting, and writes them to the chunked zarr store of :mod:`.store`, cached
under ``OUTDIR/observations`` and rebuilt when its inputs change.

Data flow: capture -> :func:`.build.load_or_build_observations` ->
:class:`.store.ObservationStore` -> the polarimetric stages
(:mod:`polarbssrdf.inverse.polarimetric.patches` reads it patch by patch).
This folder uses no stage.
"""
