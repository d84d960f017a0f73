"""What ``reconstruct`` says last: the next command that applies (issue 21, item 13).

It always said "score it with 'polarbssrdf evaluate OUTDIR'", also for a
capture without truth (evaluate refused it) and with ``--frame 2`` (evaluate
then looked for frame 0's maps). Pure function of the capture's truth: no run.
"""

from __future__ import annotations

from types import SimpleNamespace

from polarbssrdf.inverse.commands import closing_line


def _capture(texture_size=None, frames=(0, 1, 2)):
    truth = None if texture_size is None else SimpleNamespace(
        texture_size=texture_size, maps=[SimpleNamespace(frame=f) for f in frames])
    return SimpleNamespace(truth=truth)


def test_with_truth_the_line_gives_the_frame_to_score():
    line = closing_line("out", 2, [], 32, _capture(32))
    assert "score it with 'polarbssrdf evaluate out --frame 2'" in line
    assert "score it with 'polarbssrdf evaluate out'" in closing_line("out", 0, [], 32,
                                                                       _capture(32))


def test_without_truth_it_offers_the_held_out_re_render_or_the_report():
    line = closing_line("out", 0, ["cam03"], 32, _capture())
    assert "score it" not in line and "the capture has no ground truth" in line
    assert "'polarbssrdf evaluate out' re-renders the held-out camera cam03" in line
    line = closing_line("out", 0, [], 32, _capture())
    assert "score it" not in line and "'polarbssrdf evaluate" not in line
    assert "no camera was held out" in line and "'polarbssrdf report out'" in line


def test_truth_of_another_size_or_without_the_frame_is_named():
    line = closing_line("out", 0, [], 32, _capture(64))
    assert "score it" not in line and "64 x 64" in line and "--texture 64" in line
    line = closing_line("out", 5, ["cam01"], 32, _capture(32, frames=(0,)))
    assert "no frame 5" in line and "evaluate out --frame 5' re-renders" in line


def test_an_unreadable_capture_leaves_the_report():
    line = closing_line("out", 0, ["cam03"], 32, None)
    assert line.endswith("see them with 'polarbssrdf report out'") and "evaluate" not in line


def test_the_confident_share_over_frames_is_not_a_range_of_one_value(capsys):
    """Issue 32, item 14: equal shares printed "98.5-98.5%"."""
    from polarbssrdf.inverse.pipeline import say_confidence

    def share(fraction):
        return {"confident_fraction": fraction, "confident_texels": 985,
                "surface_texels": 1000}

    say_confidence("dynamic", {1: share(0.985), 2: share(0.9851)})
    assert "98.5% (every one of 2 frames)" in capsys.readouterr().err
    say_confidence("dynamic", {1: share(0.97), 2: share(0.985)})
    assert "97.0-98.5% (over 2 frames)" in capsys.readouterr().err
