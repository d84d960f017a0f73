"""The acquisition stages: from a capture to per-texel maps (supplement sec. 5 and 6).

Data flows one way: texture-space observations (:mod:`.observations`) -> the
per-texel-view model (:mod:`.model`, which evaluates :mod:`polarbssrdf.optics`)
-> losses (:mod:`.losses`, eq. 26-35) -> the patch optimizer
(:mod:`.optimize`) -> the static stage (:mod:`.static`), written in the result
format (:mod:`.result`) that mirrors a capture's truth maps.
"""
