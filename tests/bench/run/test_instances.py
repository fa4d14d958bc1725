"""Instances as the unit of replication: the sweep key ``instance`` pairs runs across optimisers.

Every optimiser of a sweep sees the same problem on the same instance (same f at the same x), and
another instance is another problem; records, job identities and job folders name the instance;
the optimiser's seed follows it unless set; a sweep over instances resumes bit-exactly; a truth
outside the search bounds is warned about before any work."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.problems.base import build_problem
from bench.records import RECORD, read_eval_log
from bench.run.preflight import compose_job

SHORT_SIM = "problem.params.sim={duration_s:14.0,n_stops:0}"


def _sweep(tmp_path, *args, name="s"):
    from bench.__main__ import main

    main(["problem=sphere", "report=false", "progress=false", *args, f"hydra.sweep.dir={tmp_path / name}"])
    return tmp_path / name


def _records(sweep) -> dict:
    return {p.parent.relative_to(sweep).as_posix(): json.loads(p.read_text()) for p in sweep.rglob(RECORD)}


def test_records_folders_and_job_keys_name_the_instance(tmp_path):
    sweep = _sweep(tmp_path, "optimizer=random,cmaes", "instance=range(2)", "budget.evals=20")
    records = _records(sweep)
    assert sorted(records) == ["sphere/cmaes/i0", "sphere/cmaes/i1", "sphere/random/i0", "sphere/random/i1"]
    for folder, record in records.items():
        instance = int(folder[-1])
        assert record["instance"] == instance and record["identity"]["instance"] == instance
        assert record["seed"] == instance  # the seed follows the instance unless set
        assert record["config"]["problem"]["params"]["instance"] == instance
        assert json.loads((sweep / folder / "job.json").read_text())["identity"]["instance"] == instance
    keys = {folder: r["job_key"] for folder, r in records.items()}
    assert len(set(keys.values())) == 4  # the instance is part of every job's identity
    # the records the report reads carry it as a column
    from bench.records import load_records

    assert sorted(load_records([sweep])["instance"]) == [0, 0, 1, 1]


def test_a_seed_set_apart_from_the_instance_gets_its_own_folder(tmp_path):
    sweep = _sweep(tmp_path, "optimizer=random", "instance=1", "seed=range(2)", "budget.evals=8")
    records = _records(sweep)
    assert sorted(records) == ["sphere/random/i1", "sphere/random/i1-seed0"]
    assert {r["seed"] for r in records.values()} == {0, 1} and {r["instance"] for r in records.values()} == {1}


def _problem(*overrides):
    return build_problem(compose_job(list(overrides)))


@pytest.mark.parametrize("name", ["sphere", "rastrigin", "rosenbrock"])
def test_optimisers_on_one_instance_see_one_function_and_instances_differ(name):
    rng = np.random.default_rng(0)
    a = _problem(f"problem={name}", "instance=3", "optimizer=random")
    b = _problem(f"problem={name}", "instance=3", "optimizer=cmaes")
    other = _problem(f"problem={name}", "instance=4", "optimizer=random")
    plain = _problem(f"problem={name}", "instance=0", "optimizer=random")
    X = a.space.lower + rng.random((16, a.space.dim)) * (a.space.upper - a.space.lower)
    np.testing.assert_array_equal(a.evaluate(X)[0], b.evaluate(X)[0])
    assert not np.allclose(a.evaluate(X)[0], other.evaluate(X)[0])
    assert not np.allclose(a.truth, other.truth)
    for problem in (a, other, plain):  # each instance's optimum is its truth, f = 0, inside the box
        assert problem.evaluate(problem.truth[None])[0][0] == pytest.approx(0.0, abs=1e-20)
        assert np.all((problem.truth > problem.space.lower) & (problem.truth < problem.space.upper))
    # instance 0 is the plain function: the minimum at the paper's PSO-GA point, unrotated
    from avio.reference import PAPER_TABLE1

    np.testing.assert_array_equal(plain.truth, [PAPER_TABLE1[n][3] for n in plain.space.names])


def test_synthetic_instances_are_cameras_and_drives_shared_by_the_optimisers():
    common = ["problem=synthetic", SHORT_SIM, "problem.params.holdout=null"]
    a = _problem(*common, "instance=2", "optimizer=random")
    b = _problem(*common, "instance=2", "optimizer=pso")
    other = _problem(*common, "instance=3", "optimizer=random")
    assert a.params.data_seed == 2 and other.params.data_seed == 3
    X = np.stack([a.space.reference, (a.space.lower + a.space.upper) / 2])
    np.testing.assert_array_equal(a.evaluate(X)[0], b.evaluate(X)[0])
    assert not np.allclose(a.evaluate(X)[0], other.evaluate(X)[0])
    assert not np.allclose(a.truth, other.truth)  # another camera


def test_a_sweep_over_instances_resumes_bit_exactly(tmp_path):
    args = ["optimizer=random,cmaes", "instance=range(2)", "budget.evals=60"]
    full = _records(_sweep(tmp_path, *args, name="full"))
    cut = _sweep(tmp_path, *args, name="cut")
    job = cut / "sphere" / "cmaes" / "i1"
    lines = (job / "evals.jsonl").read_text().splitlines(keepends=True)
    (job / "evals.jsonl").write_text("".join(lines[:2]) + lines[2][:15])  # killed mid-write of batch 3
    (job / RECORD).unlink()
    resumed = _records(_sweep(tmp_path, *args, name="cut"))
    for folder, record in full.items():
        assert resumed[folder]["job_key"] == record["job_key"] and resumed[folder]["best_f"] == record["best_f"]
        assert resumed[folder]["best_x"] == record["best_x"]
    assert [e["f"] for e in read_eval_log(job)] == [e["f"] for e in read_eval_log(tmp_path / "full" / "sphere" / "cmaes"
                                                                              / "i1")]


def test_another_instance_in_a_finished_folder_is_refused(tmp_path, capsys):
    from bench.__main__ import main

    _sweep(tmp_path, "optimizer=random", "instance=1", "budget.evals=8", "hydra.sweep.subdir=fixed")
    with pytest.raises(SystemExit) as exit_info:
        main(["problem=sphere", "report=false", "optimizer=random", "instance=2", "budget.evals=8",
              "hydra.sweep.subdir=fixed", f"hydra.sweep.dir={tmp_path / 's'}"])
    assert exit_info.value.code == 2
    assert "instance: 1 -> 2" in capsys.readouterr().err


def test_a_truth_outside_the_bounds_is_warned_about_before_the_sweep_starts(tmp_path, capsys):
    from bench.__main__ import main

    main(["problem=synthetic", SHORT_SIM, "problem.params.holdout=null", "problem.params.bounds={fx:[710,719]}",
          "optimizer=random", "instance=range(2)", "budget.evals=4", "report=false", "progress=false",
          f"hydra.sweep.dir={tmp_path / 's'}"])
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if line.startswith("warning: problem synthetic")]
    assert len(warnings) == 1, err  # one line for the problem, whatever its number of instances
    # instance 0's camera has fx 719.33 px, instance 1's 717.72 px (inside; its roll and yaw lie outside the
    # paper's Euler bounds: the cameras' pitch is near -90 deg, where roll and yaw swing)
    assert "the truth lies outside the search bounds on 2 of 2 instances (0, 1): fx up to 0.329 px above 719," \
        in warnings[0]
    assert err.index(warnings[0]) < err.index("Sweep: 2 jobs")  # before any work


def test_the_truth_warning_names_each_variable_and_by_how_much():
    from types import SimpleNamespace

    from bench.problems.analytic import paper_box_space
    from bench.run.design_checks import TruthWarnings, truth_outside

    space = paper_box_space()
    truth = space.reference.copy()
    truth[0], truth[9] = space.upper[0] + 2.5, space.lower[9] - 0.125
    problem = SimpleNamespace(space=space, truth=truth)
    assert [(v, by) for v, _, _, _, by in truth_outside(problem)] == [("fx", 2.5), ("tz", -0.125)]
    warnings = TruthWarnings()
    warnings.add("p", 0, problem)
    warnings.add("p", 1, SimpleNamespace(space=space, truth=space.reference))
    assert warnings.lines() == ["warning: problem p: the truth lies outside the search bounds on 1 of 2 instances "
                                f"(0): fx 2.5 px above {space.upper[0]:g}, tz 0.125 m below {space.lower[9]:g}; no "
                                "optimiser can reach it (widen problem.params.bounds)"]
    assert truth_outside(SimpleNamespace(space=space, truth=None)) == []


def test_sweeping_seeds_on_the_default_instances_is_noted_before_the_sweep_starts():
    from bench.run.design_checks import seed_sweep_note

    note = seed_sweep_note(["optimizer=cmaes", "seed=range(5)"], "range(0,12)")
    assert note and "instance=range(0,12)" in note and "instance='range(k)'" in note
    assert seed_sweep_note(["instance=range(3)", "seed=range(5)"], "range(0,12)") is None  # both chosen
    assert seed_sweep_note(["seed=7"], "range(0,12)") is None  # one seed: the optimiser's draw set apart
    assert seed_sweep_note(["seed=1,2"], None) is None  # no default instance sweep
