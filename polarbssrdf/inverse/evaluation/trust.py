"""Whether a run's uncertainty can be trusted, from the run's own data (no truth needed).

The static stage's confidence channel is ``min(1, n / 8)`` for a texel with ``n`` usable
texel-views (:data:`~polarbssrdf.inverse.polarimetric.fit.FULL_CONFIDENCE_VIEWS`), so the
number of views behind every confident texel can be read back from the map file.

**The criterion** (:func:`views_check`): the median number of usable views over the
confident texels of the static frame must be at least :data:`VIEWS_NEEDED`, the number of
glossy-lobe parameters per texel (:data:`GLOSSY_LOBE_PARAMETERS`). Why that number:

* each usable texel-view gives the glossy lobes one specular sample, ``I_s = I0 - I90`` at
  one half-vector angle; ``rho_s`` and ``rho_ss`` are grey, so the bands repeat that one
  number rather than add to it;
* the two lobes have four parameters per texel (amplitude and roughness of each), which
  only the change of that sample with the angle tells apart. With fewer samples than
  parameters every lobe fits its samples exactly whatever its error: the fit's own
  residual check (the chi-square behind ``residual_limit``) has no degree of freedom left
  and cannot see the error, and the values come from the smoothness prior and the start;
* ``eta`` is fitted on the subsurface polarization that remains once the glossy part is
  subtracted (eq. 29, ``I_xi = I_s - glossy``), and the albedo through ``eta``'s
  transmittance: the lobes' error moves both, alike in every band (the band-common error
  a chromophore fit is most sensitive to, docs/biophysical.md), and the biophysical
  stage's posterior std does not carry it.

Measured (synthetic faces, 128^2 texels): a 4-view ring sees a cheek texel with a median
of 2 usable views whether 3 or 4 cameras are fitted, and all six glossy and geometric maps
then lose to the best constant map, while the specular term of the loss ends at 0.07-0.11
per texel-view, a tenth of the noise unit the subsurface term settles at (the lobes fit
their samples, not the light); 7 fitted views of an 8-view ring give a median of 4. The
median (not the mean, not every texel) so that a rim of grazing texels does not decide
for a surface that is well covered elsewhere.

The biophysical maps (:func:`bio_map_notes`): a chromophore map held at its face mean or
at the first frame's map, or whose posterior std is close to its prior spread
(:data:`PRIOR_DOMINATED_VARIANCE`), was not measured, which the report and the terminal
say beside it.
"""

from __future__ import annotations

import numpy as np

from polarbssrdf.inverse.polarimetric.fit import FULL_CONFIDENCE_VIEWS

GLOSSY_LOBE_PARAMETERS = ("rho_s", "alpha_s", "rho_ss", "alpha_ss")
"""The per-texel parameters that only the angular change of the specular sample tells."""

VIEWS_NEEDED = len(GLOSSY_LOBE_PARAMETERS)
"""Usable views per confident texel (median) below which the maps and the std are not
trusted (:func:`views_check`)."""


def usable_views(confidence) -> np.ndarray:
    """Usable texel-views per texel read back from a confidence map ``min(1, n / 8)``
    (views, as float; a texel at confidence 1 counts as
    :data:`~polarbssrdf.inverse.polarimetric.fit.FULL_CONFIDENCE_VIEWS`, at least that many)."""
    confidence = np.nan_to_num(np.asarray(confidence, np.float64), nan=0.0)
    return np.round(np.clip(confidence, 0.0, 1.0) * FULL_CONFIDENCE_VIEWS)


def views_check(confidence, valid=None) -> dict | None:
    """:data:`VIEWS_NEEDED` against the views behind the confident texels on the mesh.

    ``confidence``: the static frame's confidence map; ``valid``: texels on the mesh
    (optional: the static stage writes confidence 0 off the mesh). Returns ``{"median_views", "views_needed", "confident_texels", "trusted"}`` (views
    are counts of texel-views), or None when no texel on the mesh is confident.
    """
    confidence = np.asarray(confidence, np.float64)
    confident = np.nan_to_num(confidence) > 0
    if valid is not None:
        confident &= np.asarray(valid, bool)
    if not confident.any():
        return None
    median = float(np.median(usable_views(confidence)[confident]))
    return {"median_views": median, "views_needed": VIEWS_NEEDED,
            "confident_texels": int(confident.sum()), "trusted": median >= VIEWS_NEEDED}


def views_text(check) -> str:
    """The views figure of a failed :func:`views_check`: "a median of 2 usable views per
    confident texel, fewer than the 4 ..."."""
    return (f"a median of {check['median_views']:g} usable views per confident texel, fewer "
            f"than the {check['views_needed']} the glossy lobes need (one specular sample "
            f"per view for {', '.join(GLOSSY_LOBE_PARAMETERS)})")


def untrusted_text(check, has_std: bool) -> str:
    """What a failed :func:`views_check` means for the maps (and the biophysical std when
    ``has_std``), one sentence, plain text."""
    std = (", and the biophysical posterior std, which does not carry that error, cannot "
           "be trusted" if has_std else "")
    return (f"{views_text(check)}: those maps and eta rest on the smoothness prior and the "
            "start values where the fit's own residuals cannot show their error (the albedo "
            f"inherits eta's){std}; fit views that see each texel {check['views_needed']} or "
            "more times")


# --------------------------------------------------------------------------- biophysical maps
PRIOR_DOMINATED_VARIANCE = 0.8
"""A chromophore map whose median posterior variance is above this fraction of its prior
variance is prior-dominated: with Gaussian terms the posterior precision is the prior's
plus the data's, so above 0.8 the bands add less than a quarter of the prior's precision
and what varies in the map is not measured. (One half, where data and prior weigh alike,
flagged a cheek's C_h_out whose error was half the constant map's.)"""


def bio_map_notes(channels, metadata) -> dict:
    """Chromophore maps of one biophysical map file that are not (or barely) fitted.

    ``channels``, ``metadata``: what :func:`polarbssrdf.io.exr.read_exr` returns for a
    ``bio/maps_f####.exr``. Returns ``{name: {"kind", "label", "text"}}``: ``kind`` is
    ``"held_at_face_mean"`` (the file's ``held_at_face_mean``, written by fits that hold a
    map the bands cannot tell), ``"held_at_first_frame"`` (``held``: a later frame keeps
    the first frame's melanin) or ``"prior_dominated"`` (:data:`PRIOR_DOMINATED_VARIANCE`,
    from the ``<name>_std`` channel and the prior spread in ``noise.spread``); ``label``
    is a few words for legends and terminal lines, ``text`` a sentence.
    """
    metadata = metadata or {}
    noise = metadata.get("noise") or {}
    notes = {}
    face_means = noise.get("face_means") or {}
    held_at_mean = []
    for source in (metadata.get("held_at_face_mean"), noise.get("held_at_face_mean")):
        if source:
            held_at_mean += list(source)  # a list of names, or a dict keyed by them
    for name in dict.fromkeys(held_at_mean):
        mean = (face_means.get(name) or {}).get("mean")
        at = f" {mean:.4g}" if isinstance(mean, (int, float)) else ""
        notes[name] = {"kind": "held_at_face_mean", "label": "held at its face mean",
                       "text": f"held at its face mean{at}: not fitted (the bands cannot tell "
                               "it), its std is the prior's"}
    for name in metadata.get("held") or []:
        notes.setdefault(name, {
            "kind": "held_at_first_frame", "label": "held at the first frame's map",
            "text": "held at the first frame's map (melanin does not change within seconds): "
                    "not fitted in this frame"})
    flagged = np.asarray(channels.get("flagged", 0.0)) != 0
    for name, prior in (noise.get("spread") or {}).items():
        std = channels.get(f"{name}_std")
        if name in notes or std is None or not prior or not prior > 0:
            continue
        std = np.asarray(std, np.float64)
        use = ~flagged & np.isfinite(std) & (std > 0)
        if not use.any():
            continue
        ratio = float(np.median(std[use])) / float(prior)
        if ratio ** 2 > PRIOR_DOMINATED_VARIANCE:
            notes[name] = {"kind": "prior_dominated",
                           "label": f"prior-dominated, std {ratio:.2f}x the prior's",
                           "text": f"prior-dominated: its posterior std is {ratio:.2f}x the "
                                   f"prior spread {prior:.2g}, so the bands add less than a "
                                   "quarter of what the prior knows; what varies in this map "
                                   "is not measured"}
    return notes


def static_map_notes(metadata) -> dict:
    """The polarimetric maps of one static or dynamic map file held at one face value.

    ``metadata``: the file's metadata (:func:`polarbssrdf.io.exr.read_exr`), whose
    ``held_at_face_mean`` the static stage writes
    (:func:`polarbssrdf.inverse.polarimetric.face_level.unresolved_maps`: the map's spread
    over the confident texels was no larger than its posterior error) and the dynamic stage
    copies for the static maps it keeps. Returns ``{name: {"kind", "label", "text"}}`` as
    :func:`bio_map_notes` does."""
    notes = {}
    for name, entry in dict((metadata or {}).get("held_at_face_mean") or {}).items():
        entry = entry if isinstance(entry, dict) else {}
        level = entry.get("level", entry.get("mean"))
        at = f" {level:.4g}" if isinstance(level, (int, float)) else ""
        spread, error = entry.get("spread"), entry.get("noise_std")
        why = (f" (its fitted spread {spread:.3g} was within its posterior error {error:.3g})"
               if isinstance(spread, (int, float)) and isinstance(error, (int, float)) else "")
        notes[name] = {"kind": "held_at_face_mean", "label": "held at its face level",
                       "text": f"held at one face value{at}: the views do not resolve its "
                               f"variation{why}; its std is that spread"}
    return notes


NOTE_WORDS = {"held_at_face_mean": "held at its face mean", "prior_dominated": "prior-dominated",
              "held_at_first_frame": "held at the first frame's map"}
"""A few words per kind of :func:`bio_map_notes`."""

NEWS = ("held_at_face_mean", "prior_dominated")
"""The kinds a terminal line names (a later frame holding the first frame's melanin is the
stage's design, not news)."""


def notes_by_map(notes_by_frame, kinds=tuple(NOTE_WORDS)) -> dict:
    """``{frame: bio_map_notes}`` -> ``{name: "prior-dominated (frames 0, 1); ..."}``: for
    each map, each kind of ``kinds`` with the frames it holds in."""
    frames_of = {}
    for frame, notes in sorted(notes_by_frame.items(), key=lambda item: int(item[0])):
        for name, note in notes.items():
            if note["kind"] in kinds:
                frames_of.setdefault(name, {}).setdefault(note["kind"], []).append(str(frame))
    return {name: "; ".join(f"{NOTE_WORDS[kind]} (frame{'s' if len(frames) > 1 else ''} "
                            f"{', '.join(frames)})" for kind, frames in per_kind.items())
            for name, per_kind in frames_of.items()}


def unmeasured_summary(notes_by_frame) -> str:
    """One phrase for a terminal line: ``{frame: bio_map_notes}`` -> "beta_m prior-dominated
    (frames 0, 1), C_h_in held at its face mean (frame 0)"; "" when there is nothing to say."""
    return ", ".join(f"{name} {text}" for name, text in notes_by_map(notes_by_frame, NEWS).items())
