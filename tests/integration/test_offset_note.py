"""A model fitted without its output offset (lugre's default, paper 002's parameters) on captures
whose output rests away from the model's zero: the console names the option that fixes it.

Found by a blind test: a capture of the virtual stage with its sensor 50 µm off gave R² = −20 with
only a bound note (nothing said that lugre has no offset by default)."""

from __future__ import annotations

from typer.testing import CliRunner

from hystfit import synth
from hystfit.cli import app

runner = CliRunner()


def _capture(path, shift_um: float) -> None:
    t, u = synth.raised_cosine(60.0, 20.0, 3, 5_000)
    plant = synth.Plant.default().with_effects(synth.Effects(noise=True, noise_sigma_um=0.01))
    synth.write_capture(path, t, u, synth.simulate_plant(plant, t, u, seed=0) + shift_um, "um")


def test_a_fit_without_offset_whose_residual_is_a_constant_names_the_option(tmp_path):
    _capture(tmp_path / "off50.csv", 50.0)
    res = runner.invoke(app, ["identify", str(tmp_path / "off50.csv"), "--model", "lugre", "--no-plots",
                              "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    assert "lugre is fitted without an output offset (offset=false)" in res.output
    assert "add --model-option offset=true" in res.output
    fixed = runner.invoke(app, ["identify", str(tmp_path / "off50.csv"), "--model", "lugre", "--no-plots",
                                "--model-option", "offset=true", "--out", str(tmp_path / "o2")])
    assert fixed.exit_code == 0 and "without an output offset" not in fixed.output


def test_no_note_where_the_output_rests_where_the_model_does(tmp_path):
    _capture(tmp_path / "rc.csv", 0.0)
    res = runner.invoke(app, ["identify", str(tmp_path / "rc.csv"), "--model", "lugre", "--no-plots",
                              "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    assert "output offset" not in res.output
