"""The preflight's composition shortcut gives every job exactly the config Hydra composes for it."""

from __future__ import annotations

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

from bench.run.compose_cache import JobComposer, _fingerprint, job_part
from bench.run.preflight import CONF_DIR, _job_dir, _job_part, expand_jobs


def test_shortcut_configs_equal_hydras_for_every_job():
    argv = ["problem=sphere,rastrigin", "optimizer=random,pso", "instance=0", "seed=range(2)", "budget.evals=10,20",
            "progress_every_s=2.5", "hydra.sweep.dir=/tmp/x", "hydra.sweep.subdir=${hydra.job.override_dirname}"]
    hydra_overrides = argv[-2:]
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3", job_name="preflight"):
            jobs = expand_jobs(argv[:-2])
            composer = JobComposer(hydra_overrides)
            for overrides in jobs:
                fast = composer(overrides)
                got = (_fingerprint(fast), job_part(fast), _job_dir(fast))
                truth = compose("config", overrides=overrides + hydra_overrides, return_hydra_config=True)
                assert got == (_fingerprint(truth), _job_part(truth), _job_dir(truth)), overrides
    finally:
        GlobalHydra.instance().clear()
    assert len(jobs) == 16
    # one full composition per kind of job (problem x optimizer), and one more to check each kind
    assert composer.full == 2 * 4


def test_top_level_keys_read_from_config_yaml_are_those_hydra_composes():
    """compose_cache.top_level_keys skips a composition (~0.17 s a command) by reading config.yaml; it must
    name exactly the keys the composed config has, or a valid override would be refused (or a typo let by)."""
    from bench.run.compose_cache import top_level_keys

    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3", job_name="preflight"):
            composed = set(compose("config").keys())
            assert top_level_keys(CONF_DIR, []) == composed
            assert {"problem", "optimizer", "budget", "verdict", "instance"} <= composed
            assert top_level_keys(CONF_DIR, [f"hydra.searchpath=[file://{CONF_DIR}]"]) == composed
    finally:
        GlobalHydra.instance().clear()
