"""The result directory: what every stage writes and the later ones read (no stage inside).

:mod:`.directory`: ``result.json`` and the per-stage, per-frame float32 EXR
maps in the channel names, texture convention and units of a capture's truth
maps; ``metrics.json`` (loss histories), ``timings.json``; preparing,
resuming and extending a run's directory; :class:`.directory.ResultDirectory`,
which reads a result from Python. :mod:`.previews`: PNG previews with colour
bars and units. :mod:`.fill`: filling unconfident texels from their neighbours.

Data flow: the static, dynamic and biophysical stages write here; each later
stage, the evaluation and the report read from here.
"""
