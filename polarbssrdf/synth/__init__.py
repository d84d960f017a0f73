"""Synthetic captures with ground truth: orchestrates :mod:`polarbssrdf.render` and
:mod:`polarbssrdf.capture`, writes the capture format of :mod:`polarbssrdf.io`."""
