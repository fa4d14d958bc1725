"""studies/objective/noise_consistency.py: the noise-model check a user runs on a new dataset."""

from __future__ import annotations


def test_the_simulated_noise_is_consistent_and_a_too_wide_one_is_not(capsys, load_script):
    module = load_script("noise_consistency")
    module.main(["--problem", "synthetic", "--sigmas", "0.7", "2.1", "--imu-scales", "1.0", "--threads", "1",
                 "problem.params.holdout=null"])
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[2:]]
    nis = {float(r[0]): float(r[2]) for r in rows}
    assert 0.9 <= nis[0.7] <= 1.0  # the simulator's 0.7 px: consistent (the gate truncates to ~0.96)
    assert nis[2.1] < 0.3  # three times too wide: NIS/dof far below 1, as on the real sources
