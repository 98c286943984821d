"""simulate's note on an error that is mostly a constant names the causes that fit the case."""

from __future__ import annotations

from types import SimpleNamespace

from hystfit.predict import _constant_note


def _pf(*blocks: str):
    model = SimpleNamespace(blocks=tuple(SimpleNamespace(name=b) for b in blocks))
    return SimpleNamespace(unit="um", cells=(SimpleNamespace(model=model),))


def test_the_note_blames_a_moved_zero_only_where_nothing_else_explains_a_constant():
    plain = _constant_note(_pf(), 0.6, 0.63, outside=False)
    assert "a sensor zero that moved" in plain and "--align-offset" in plain
    # extrapolated or clamped cells shift the prediction as much (a blind test's 80 V capture of a 60 V table)
    out = _constant_note(_pf(), 0.6, 0.63, outside=True)
    assert "outside its cells' range" in out and "before blaming a sensor zero" in out
    # creep starts from rest at the capture's first sample (a second half of a recording: -3.5 µm)
    creep = _constant_note(_pf("creep", "delay"), -3.5, 3.57, outside=False)
    assert "creep starts from rest" in creep and "--align-offset" in creep
