"""bench.verdict_settings: the ``verdict:`` section of config.yaml, checked in one place for the sweep
(at its start) and the report (on the records it reads)."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from bench.verdict_settings import (
    TESTS,
    VerdictSettings,
    VerdictSettingsError,
    record_column,
    verdict_settings,
)


def test_the_tests_are_the_reports_post_hocs():
    from bench.report.verdict import POSTHOCS

    assert TESTS == POSTHOCS


def test_the_shipped_settings_are_valid_and_give_each_problem_its_rope():
    from bench.run.preflight import CONF_DIR

    node = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "config.yaml").verdict)
    settings = verdict_settings(node, keys=["instance", "seed", "problem.params.data_seed"])
    assert (settings.key, settings.test, settings.family, settings.alpha) == ("instance", "wilcoxon", "leader", 0.05)
    assert settings.objective_ropes(["synthetic", "sphere"]) == {"synthetic": 0.0, "sphere": 0.0}
    assert settings.metric_rope("ray_error_deg") is None


def test_a_rope_per_problem_and_per_calibration_error():
    settings = verdict_settings({"rope": {"default": 0.1, "synthetic": 0.01, "rotation_error_deg": 0.05}})
    assert settings.objective_ropes(["synthetic", "sphere"]) == {"synthetic": 0.01, "sphere": 0.1}
    assert settings.metric_rope("rotation_error_deg") == 0.05 and settings.metric_rope("focal_error_px") is None
    assert verdict_settings({"rope": 0.02}).objective_rope("kitti00") == 0.02


def test_defaults_when_there_is_no_section():
    assert verdict_settings(None) == VerdictSettings()
    assert VerdictSettings().objective_rope("anything") == 0.0


@pytest.mark.parametrize("node, message", [
    ({"test": "tukey"}, "verdict.test = 'tukey': unknown test"),
    ({"family": "pairs"}, "verdict.family = 'pairs'"),
    ({"alpha": 1.0}, "verdict.alpha = 1.0: must be a number in (0, 1)"),
    ({"alpha": True}, "verdict.alpha = True"),
    ({"rope": {"synthetc": 0.1}}, "verdict.rope.synthetc: unknown ROPE name"),
    ({"rope": {"default": -0.01}}, "verdict.rope.default = -0.01: must be a finite number >= 0"),
    ({"rope": {"default": float("nan")}}, "verdict.rope.default = nan"),
    ({"rope": -0.1}, "verdict.rope = -0.1: must be a finite number >= 0"),
    ({"rope": "wide"}, "verdict.rope must be a number >= 0 or a section"),
    ({"key": ""}, "verdict.key = '': must be the name of a record key"),
    ({"colour": "red"}, "verdict: unknown setting(s) ['colour']"),
])
def test_bad_settings_name_their_key(node, message):
    with pytest.raises(VerdictSettingsError) as err:
        verdict_settings(node)
    assert message in str(err.value)


def test_a_pairing_key_the_records_lack_is_refused_and_one_they_hold_is_found():
    columns = ["problem", "optimizer", "instance", "seed", "config.problem.params.data_seed"]
    assert record_column("instance", columns) == "instance"
    assert record_column("problem.params.data_seed", columns) == "config.problem.params.data_seed"
    assert verdict_settings({"key": "problem.params.data_seed"}, keys=columns).key == "problem.params.data_seed"
    with pytest.raises(VerdictSettingsError, match="verdict.key = 'camera': the records lack this key"):
        verdict_settings({"key": "camera"}, keys=columns)


def test_a_problem_the_caller_names_may_carry_a_rope():
    assert verdict_settings({"rope": {"mine": 0.2}}, problems=["mine"]).objective_rope("mine") == 0.2
