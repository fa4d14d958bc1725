"""``bench.problems.make``: the harness's objective as a plain callable, driven by nevergrad, pymoo,
optuna and ioh, and the snippets of docs/guide/interop.md run as written."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from bench.problems import CallableProblem, ProblemError, make
from bench.problems.base import _problem_cached
from bench.run.preflight import compose_job
from bench.space import SpaceError

DOCS = Path(__file__).resolve().parents[3] / "docs" / "guide" / "interop.md"
SHORT_DRIVE = {"duration_s": 12, "n_stops": 0}


def fresh_evaluate(config: dict, X: np.ndarray) -> np.ndarray:
    """f of X from a problem built anew (not the process cache) from the harness's composed config."""
    problem = _problem_cached.__wrapped__(config["name"], json.dumps(config["params"], sort_keys=True))
    return problem.evaluate(np.asarray(X, float))[0]


class Recorder:
    """The problem as each library calls it, remembering every point and value."""

    def __init__(self, problem: CallableProblem) -> None:
        self.problem, self.X, self.f = problem, [], []

    def __call__(self, X):
        X = np.asarray(X, float)
        f = self.problem(X)
        self.X.extend(np.atleast_2d(X))
        self.f.extend(np.atleast_1d(f))
        return f

    def check_against_the_harness(self, config: dict, at_least: int) -> None:
        assert len(self.f) >= at_least
        np.testing.assert_array_equal(np.array(self.f), fresh_evaluate(config, np.array(self.X)))


@pytest.fixture(scope="module")
def sphere():
    return make("sphere")


@pytest.fixture(scope="module")
def sphere_config():
    return compose_job(["problem=sphere"])["problem"]


def test_make_is_the_problem_the_harness_composes(sphere, sphere_config):
    assert sphere.config == sphere_config
    assert sphere.d == 10 and len(sphere.names) == len(sphere.units) == 10
    np.testing.assert_array_equal(sphere.x0, sphere.problem.space.reference)
    np.testing.assert_array_equal(sphere.lower, sphere.problem.space.lower)
    np.testing.assert_array_equal(sphere.upper, sphere.problem.space.upper)
    X = np.random.default_rng(0).uniform(sphere.lower, sphere.upper, (5, sphere.d))
    f, metrics = sphere(X, with_metrics=True)
    assert f.shape == (5,)
    np.testing.assert_array_equal(f, fresh_evaluate(sphere_config, X))
    np.testing.assert_array_equal(metrics["distance_to_optimum"], sphere.metrics(X)["distance_to_optimum"])
    one = sphere(X[0])
    assert isinstance(one, float) and one == f[0]
    assert sphere.metrics(X[0]) == {"distance_to_optimum": metrics["distance_to_optimum"][0]}
    assert sphere(sphere.truth) == 0.0


def test_params_merge_over_the_yaml_like_command_line_overrides():
    config = make("sphere", delay_s_per_batch=0.0).config
    assert config == compose_job(["problem=sphere", "problem.params.delay_s_per_batch=0.0"])["problem"]


def test_bad_name_params_and_points_raise_the_harness_errors(sphere):
    with pytest.raises(KeyError, match="unknown problem 'nope'; valid names: .*sphere"):
        make("nope")
    with pytest.raises(TypeError, match="unexpected keyword argument 'colour'"):
        make("sphere", colour="red")
    with pytest.raises(ProblemError, match="delay_s_per_batch must be >= 0"):
        make("sphere", delay_s_per_batch=-1.0)
    with pytest.raises(SpaceError, match="outside"):
        sphere(sphere.upper + 1.0)


def test_nevergrad(sphere, sphere_config):
    import nevergrad as ng

    recorder = Recorder(sphere)
    param = ng.p.Array(init=sphere.x0, lower=sphere.lower, upper=sphere.upper)
    ng.optimizers.NGOpt(parametrization=param, budget=8).minimize(recorder)
    recorder.check_against_the_harness(sphere_config, at_least=8)


def test_pymoo(sphere, sphere_config):
    from pymoo.algorithms.soo.nonconvex.ga import GA
    from pymoo.core.problem import Problem
    from pymoo.optimize import minimize

    recorder = Recorder(sphere)

    class Wrapped(Problem):
        def __init__(self):
            super().__init__(n_var=sphere.d, n_obj=1, xl=sphere.lower, xu=sphere.upper)

        def _evaluate(self, X, out, *args, **kwargs):
            out["F"] = recorder(X)

    minimize(Wrapped(), GA(pop_size=4), ("n_eval", 8), seed=1)
    recorder.check_against_the_harness(sphere_config, at_least=8)


def test_optuna(sphere, sphere_config):
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    recorder = Recorder(sphere)

    def objective(trial):
        return recorder(np.array([trial.suggest_float(n, lo, hi)
                                  for n, lo, hi in zip(sphere.names, sphere.lower, sphere.upper)]))

    optuna.create_study(sampler=optuna.samplers.TPESampler(seed=0)).optimize(objective, n_trials=6)
    recorder.check_against_the_harness(sphere_config, at_least=6)


def test_ioh(sphere, sphere_config, tmp_path):
    import ioh

    recorder = Recorder(sphere)
    span = sphere.upper - sphere.lower
    f = ioh.wrap_problem(lambda u: recorder(sphere.lower + np.asarray(u) * span), name="avio_test_make_sphere",
                         dimension=sphere.d, lb=0.0, ub=1.0)
    logger = ioh.logger.Analyzer(root=str(tmp_path), folder_name="rs", algorithm_name="rs")
    f.attach_logger(logger)
    rng = np.random.default_rng(0)
    values = [f(rng.uniform(0.0, 1.0, sphere.d)) for _ in range(6)]
    logger.close()
    recorder.check_against_the_harness(sphere_config, at_least=6)
    assert values == recorder.f and f.state.current_best.y == min(values)


@pytest.mark.slow
def test_the_vio_problem_scores_as_the_harness_does():
    vio = make("synthetic", sim=SHORT_DRIVE)
    config = compose_job(["problem=synthetic", "++problem.params.sim={duration_s:12,n_stops:0}"])["problem"]
    assert vio.config == config
    X = np.stack([vio.x0, vio.lower + 0.6 * (vio.upper - vio.lower)])
    f, metrics = vio(X, with_metrics=True)
    np.testing.assert_array_equal(f, fresh_evaluate(config, X))
    assert np.isfinite(f).all() and "rotation_error_deg" in metrics and vio.f_unit == "m"


@pytest.mark.slow
def test_the_docs_snippets_run_as_written(capsys):
    blocks = re.findall(r"```python\n(.*?)```", DOCS.read_text(), re.S)
    assert len(blocks) >= 6
    for i, block in enumerate(blocks):
        exec(compile(block, f"{DOCS.name}[python block {i}]", "exec"), {"__name__": f"interop_doc_{i}"})
    out = capsys.readouterr().out
    for library in ("nevergrad", "pymoo", "optuna", "ioh"):
        assert f"{library}:" in out and f"{library} on the VIO:" in out
