"""Search spaces and the analytic problems' contract."""

from __future__ import annotations

import numpy as np
import pytest

from bench import problems
from bench.problems.analytic import AnalyticProblem, paper_box_space
from bench.problems.base import ProblemError
from bench.space import Space, SpaceError


def test_paper_space_has_table1_bounds_and_reference():
    space = paper_box_space()
    assert space.names[:4] == ("fx", "fy", "cx", "cy") and space.dim == 10
    assert space.lower[0] == 700 and space.upper[0] == 740 and space.reference[4] == pytest.approx(119.5262)


@pytest.mark.parametrize(
    "lower, upper, reference, message",
    [([1.0], [0.0], [0.5], "lower bound 1.0 is not below upper bound 0.0"),
     ([0.0], [np.inf], [0.5], "must be finite"),
     ([0.0], [1.0], [2.0], "reference 2.0 outside")],
)
def test_invalid_bounds_name_the_variable(lower, upper, reference, message):
    with pytest.raises(SpaceError, match=f"variable 'a'.*{message}"):
        Space(("a",), ("m",), np.array(lower), np.array(upper), np.array(reference))


def test_check_rejects_wrong_shapes_and_points_outside():
    space = paper_box_space()
    with pytest.raises(SpaceError, match=r"shape \(n, 10\)"):
        space.check(np.zeros(10))
    X = np.tile(space.reference, (3, 1))
    X[2, 1] = 800.0
    with pytest.raises(SpaceError, match="point 2 has fy=800.0 outside"):
        space.check(X)


@pytest.mark.parametrize("name", ["sphere", "rastrigin", "rosenbrock"])
def test_analytic_problem_is_batched_with_its_minimum_at_the_truth(name):
    problem = problems.get(name)()
    rng = np.random.default_rng(0)
    X = rng.uniform(problem.space.lower, problem.space.upper, size=(7, 10))
    f, metrics = problem.evaluate(X)
    assert f.shape == (7,) and metrics["distance_to_optimum"].shape == (7,)
    f_truth, _ = problem.evaluate(problem.truth[None])
    assert f_truth[0] == pytest.approx(0.0, abs=1e-12)
    assert np.all(f > 0)
    # one evaluation in a batch equals the same point alone
    assert problem.evaluate(X[3:4])[0][0] == f[3]


def test_unknown_problem_lists_valid_names():
    with pytest.raises(KeyError, match="valid names: .*rastrigin.*sphere"):
        problems.get("spherez")
    with pytest.raises(ProblemError, match="unknown analytic function"):
        AnalyticProblem("cube")
