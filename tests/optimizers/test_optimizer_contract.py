"""Every plugin honours the ask/tell contract: bounds, batch shapes, seeding, global RNG, yaml."""

from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest
import yaml

from optimizers import OptimizerError, registry

NAMES = registry.available()  # every registered plugin, the README example included; new ones too
DETERMINISTIC = {"nelder_mead", "lbfgsb"}  # local methods from x0: the seed changes nothing
CONF = Path(__file__).resolve().parents[2] / "bench" / "conf" / "optimizer"
# nevergrad's MetaModel (picked by NGOpt) warns on numpy >= 1.25; it is why numpy is pinned < 2.4
pytestmark = pytest.mark.filterwarnings("ignore:Conversion of an array with ndim > 0:DeprecationWarning")

# an awkward box: mixed scales, like pixels next to metres
LOWER = np.array([700.0, -100.0, 0.8, -0.5])
UPPER = np.array([740.0, -80.0, 1.3, -0.1])
X0 = np.array([718.9, -89.4, 1.1, -0.32])


def _f(X: np.ndarray) -> np.ndarray:
    u = (X - LOWER) / (UPPER - LOWER)
    return np.sum((u - 0.3) ** 2, axis=1) + 0.1 * np.sin(20 * u[:, 0])


def _drive(name: str, seed: int, rounds: int = 4, **params) -> list[np.ndarray]:
    opt = registry.get(name)(LOWER, UPPER, seed=seed, x0=X0, **params)
    asked = []
    for _ in range(rounds):
        if opt.stop is not None:
            break
        X = opt.ask()
        asked.append(X)
        opt.tell(X, _f(X))
    return asked


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_gives_identical_asks(name):
    first, second = _drive(name, seed=7), _drive(name, seed=7)
    assert len(first) == len(second) > 1
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", sorted(set(NAMES) - DETERMINISTIC))
def test_different_seeds_give_different_asks(name):
    assert not np.array_equal(_drive(name, seed=1, rounds=1)[0], _drive(name, seed=2, rounds=1)[0])


@pytest.mark.parametrize("name", NAMES)
def test_asks_are_batches_inside_the_bounds(name):
    for X in _drive(name, seed=3, rounds=6):
        assert X.ndim == 2 and X.shape[1] == LOWER.size and X.shape[0] >= 1
        assert np.all(np.isfinite(X))
        assert np.all(X >= LOWER) and np.all(X <= UPPER)


@pytest.mark.parametrize("name", NAMES)
def test_global_numpy_rng_is_untouched(name):
    np.random.seed(12345)
    before = np.random.get_state()
    _drive(name, seed=5, rounds=3)
    after = np.random.get_state()
    assert before[0] == after[0] and before[2:] == after[2:]
    np.testing.assert_array_equal(before[1], after[1])


@pytest.mark.parametrize("name", NAMES)
def test_nonfinite_values_are_survived_and_never_best(name):
    opt = registry.get(name)(LOWER, UPPER, seed=0, x0=X0)
    for k in range(3):
        X = opt.ask()
        f = _f(X)
        f[:: 2] = np.nan if k % 2 else np.inf
        if len(f) == 1 and k == 0:
            f[0] = 1.0  # a one-point batch needs one finite value somewhere for best to exist
        opt.tell(X, f)
        if opt.stop is not None:
            break
    x, fbest = opt.best
    assert np.isfinite(fbest) and np.all((x >= LOWER) & (x <= UPPER))


@pytest.mark.parametrize("name", NAMES)
def test_best_is_the_minimum_told(name):
    opt = registry.get(name)(LOWER, UPPER, seed=4, x0=X0)
    told_X, told_f = [], []
    for _ in range(3):
        X = opt.ask()
        f = _f(X)
        opt.tell(X, f)
        told_X.append(X), told_f.append(f)
    X, f = np.vstack(told_X), np.concatenate(told_f)
    x, fbest = opt.best
    assert fbest == pytest.approx(f.min())
    np.testing.assert_allclose(_f(x[None])[0], fbest)


@pytest.mark.parametrize("name", NAMES)
def test_ask_twice_without_tell_is_an_error(name):
    opt = registry.get(name)(LOWER, UPPER, seed=0, x0=X0)
    opt.ask()
    with pytest.raises(OptimizerError):
        opt.ask()


@pytest.mark.parametrize("name", NAMES)
def test_tell_with_wrong_length_is_an_error(name):
    opt = registry.get(name)(LOWER, UPPER, seed=0, x0=X0)
    X = opt.ask()
    with pytest.raises(OptimizerError):
        opt.tell(X, np.zeros(len(X) + 1))


@pytest.mark.parametrize("name", NAMES)
def test_bad_bounds_are_rejected(name):
    with pytest.raises(OptimizerError, match="lower >= upper"):
        registry.get(name)([0.0, 1.0], [1.0, 1.0], seed=0)


@pytest.mark.parametrize("name", NAMES)
def test_yaml_names_the_plugin_and_exposes_every_hyperparameter(name):
    conf = yaml.safe_load((CONF / f"{name}.yaml").read_text())
    cls = registry.get(name)
    assert conf["name"] == name and cls.registered_name == name
    signature = inspect.signature(cls.__init__).parameters
    hyper = set(signature) - {"self", "lower", "upper", "seed", "x0"}
    assert set(conf["params"]) == hyper
    for key, value in conf["params"].items():  # the yaml defaults are the code defaults
        assert value == signature[key].default, key
    opt = cls(LOWER, UPPER, seed=0, x0=X0, **conf["params"])
    assert opt.ask().shape[1] == LOWER.size


def test_registry_discovers_every_plugin_module_and_yaml():
    shipped = {"random", "psoga", "pso", "ga", "cmaes", "tpe", "nevergrad", "nelder_mead", "lbfgsb", "one_plus_one"}
    assert shipped <= set(NAMES)
    assert {p.stem for p in CONF.glob("*.yaml")} == set(NAMES)  # every plugin has a yaml, every yaml a plugin


@pytest.mark.parametrize("name", NAMES)
def test_every_plugin_uses_the_shared_base(name):
    from optimizers.base import AskTell

    cls = registry.get(name)
    assert issubclass(cls, AskTell)
    # the guards live in the base only: no plugin re-implements ask/tell/best
    for method in ("ask", "tell", "best"):
        assert method not in vars(cls), f"{name} overrides {method}"


@pytest.mark.parametrize("name", NAMES)
def test_tell_without_ask_is_an_error(name):
    opt = registry.get(name)(LOWER, UPPER, seed=0, x0=X0)
    with pytest.raises(OptimizerError, match="without a pending ask"):
        opt.tell(np.zeros((2, LOWER.size)), np.zeros(2))


@pytest.mark.parametrize("name", NAMES)
def test_negative_seed_is_refused_naming_the_key(name):
    with pytest.raises(OptimizerError, match=r"seed must be an integer >= 0, got -1"):
        registry.get(name)(LOWER, UPPER, seed=-1, x0=X0)


def test_nan_in_a_batch_does_not_become_the_parent_of_one_plus_one():
    # the (1+1)-ES took argmin(f) with NaN in f, i.e. the NaN point, as its new parent
    opt = registry.get("one_plus_one")(LOWER, UPPER, seed=0, x0=X0, batch_size=3)
    X = opt.ask()
    opt.tell(X, np.array([np.nan, 2.0, 1.0]))
    np.testing.assert_array_equal(opt.parent, X[2])
    assert opt.best[1] == 1.0


BAD_HYPERPARAMETERS = [
    ("pso", {"pop_size": 0}, "pso: pop_size must be an integer >= 2, got 0"),
    ("pso", {"pop_size": -5}, "pso: pop_size must be an integer >= 2, got -5"),
    ("pso", {"pop_size": 1}, "pso: pop_size must be an integer >= 2, got 1"),
    ("pso", {"pop_size": 1.5}, "pso: pop_size must be an integer >= 2, got 1.5"),
    ("pso", {"w": "abc"}, "pso: w must be a number in [0, inf), got 'abc'"),
    ("ga", {"pop_size": 1.5}, "ga: pop_size must be an integer >= 2, got 1.5"),
    ("cmaes", {"population_size": 1}, "cmaes: population_size must be an integer >= 2, got 1"),
    ("cmaes", {"sigma0": 0}, "cmaes: sigma0 must be a number in (0, inf), got 0"),
    ("random", {"batch_size": 0}, "random: batch_size must be an integer >= 1, got 0"),
    ("tpe", {"batch_size": 0}, "tpe: batch_size must be an integer >= 1, got 0"),
    ("one_plus_one", {"batch_size": 0}, "one_plus_one: batch_size must be an integer >= 1, got 0"),
    ("psoga", {"pop_size": 7}, "psoga: pop_size must be an even integer >= 2, got 7"),
    ("psoga", {"stop_rule": "never"}, "psoga: stop_rule must be one of patience, paper, none, got 'never'"),
    ("nevergrad", {"num_workers": True}, "nevergrad: num_workers must be an integer >= 1, got True"),
    ("lbfgsb", {"fd_step": 0.5}, "lbfgsb: fd_step must be a number in (0, 0.5), got 0.5"),
    ("nelder_mead", {"maxfev": 0}, "nelder_mead: maxfev must be an integer >= 1, got 0"),
]


@pytest.mark.parametrize("name, params, message", BAD_HYPERPARAMETERS)
def test_bad_hyperparameters_are_refused_naming_key_and_range(name, params, message):
    with pytest.raises(OptimizerError) as err:
        registry.get(name)(LOWER, UPPER, seed=0, x0=X0, **params)
    assert str(err.value) == message


def test_plugin_modules_import_their_libraries_lazily():
    import subprocess
    import sys

    modules = ["psoga", "pymoo_algorithms", "cma_es", "tpe", "nevergrad_optimizer", "scipy_local", "random_search"]
    code = ("import importlib, sys\n"
            f"for m in {modules!r}: importlib.import_module('optimizers.' + m)\n"
            "heavy = ('pymoo', 'optuna', 'nevergrad', 'cmaes', 'scipy.optimize')\n"
            "print(','.join(m for m in heavy if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.stdout.strip() == ""
