"""The base's resolution converged before any effect is tested (``converge_resolution``)."""

from __future__ import annotations

import pytest

from hystfit.diagnose import DiagnoseSettings, diagnose, withheld_effect_captures
from hystfit.factory import make_model, make_optimizer
from hystfit.registry import optimizers
from hystfit.report.diagnose_report import diagnosis_document, markdown


@pytest.fixture(scope="module")
def none_diagnosis():
    caps = withheld_effect_captures("none", 1.0, 0)
    return diagnose(caps, make_model("pi"), make_optimizer(optimizers.get("auto")),
                    settings=DiagnoseSettings(max_effects=1, placebo_draws=2))


def test_a_coarse_base_is_refined_until_its_own_error_is_below_the_noise(none_diagnosis):
    """No effect switched on: ten operators leave twice the noise on held-out data; twenty remove
    almost all of the excess mean square, and refining stops there because what is left is below
    the noise floor."""
    d = none_diagnosis
    r = d.resolution_before_effects
    sigma = d.noise["sigma"]
    assert (r["option"], r["from"], r["to"]) == ("n_operators", 10, 20)
    (step,) = r["steps"]
    assert step["adopted"] and step["reduction_mean_square"] > 0.8
    after = step["heldout_rmse_after_out"]
    assert (after ** 2 - sigma ** 2) ** 0.5 <= sigma < (step["heldout_rmse_before_out"] ** 2 - sigma ** 2) ** 0.5
    assert d.explained_by == () and d.recommended_options["n_operators"] >= 20
    doc = diagnosis_document(d)["resolution_before_effects"]
    assert doc["steps"][0]["heldout_rmse_after_um"] == after and doc["to"] == 20
    assert "Resolution of the base before any effect is tested" in markdown(d, {})


def test_switched_off_or_fixed_structure_means_no_convergence():
    caps = withheld_effect_captures("none", 1.0, 0, frequencies_Hz=(10.0, 40.0), steps_s=0.0)
    opt = make_optimizer(optimizers.get("auto"))
    d = diagnose(caps, make_model("pi"), opt, settings=DiagnoseSettings(max_effects=1, placebo_draws=1,
                                                                      resolution_check=False))
    assert d.resolution_before_effects is None and d.recommended_options == {}
    with pytest.raises(Exception, match="resolution_threshold"):
        DiagnoseSettings(resolution_threshold=1.5)
