"""The paper's hybrid PSO–GA (its Fig. 4): one PSO step, then one GA step, repeated.

Search happens in normalised coordinates ``u = (x - lower) / (upper - lower)`` in [0, 1]^d, so
that velocities, mutation strengths and the stop rule treat every variable alike whatever its
unit (pixels, degrees, metres); ``ask`` returns raw points.
"""

from __future__ import annotations

import numpy as np

from optimizers.base import AskTell
from optimizers.registry import register

_STOP_RULES = ("patience", "paper", "none")


@register("psoga")
class PsoGa(AskTell):
    """Hybrid particle swarm / genetic algorithm; the batch is the swarm (``pop_size`` points).

    Cycle (each phase is one ``ask``/``tell`` of ``pop_size`` points):
    (1) uniform random swarm in the box; (2) PSO step: ``v = w v + c1 r1 (pbest - u) + c2 r2
    (gbest - u)``, ``|v| <= v_max``, ``u += v``, clipped to the box (the velocity component
    that hit a wall is zeroed); (3) GA step on the PSO swarm: binary tournament selection,
    SBX crossover and polynomial mutation (pymoo operators) make ``pop_size`` children;
    "keep the best population": the children and the swarm are merged and the best
    ``pop_size`` survive — a child takes the slot of the worst particle it beats, keeping that
    slot's velocity and personal best memory; then back to (2). One *iteration* = (2) + (3).

    Stop rules (checked after each iteration; ``stop_rule``):
    - ``"patience"`` (default): the best f has not improved by more than ``tol`` (relative,
      ``f_old - f_new > tol * max(|f_old|, 1e-12)``) for ``patience`` iterations.
    - ``"paper"``: ``Δuᵀ Δu <= epsilon`` with Δu the change of the best point between two
      iterations, in normalised units (ε = 0.001 ⇔ ‖Δu‖ <= 0.032, a Euclidean move of 3 % of one
      variable's range); in raw units the pixel variables (ranges of 20–40 px) would swamp the
      metre ones (0.4–0.5 m). It fires as soon as the best point does not move for one
      iteration, which happens early: on the 10-D analytic problems it stopped all 10 runs
      after a median 140–260 evaluations, at median f far above the same runs continued to
      1,000 (sphere 4.1 vs 0.14, rastrigin 51 vs 25, rosenbrock 48 vs 4.8; random search
      reaches 54 on rastrigin at 1,000). The patience rule (20 iterations) never fired by 1,000
      evaluations; by 5,000 it stopped 2/10 rastrigin runs stuck in a local minimum, none on
      sphere/rosenbrock, and the medians equal those without a stop rule
      (``python benchmarks/bench_optimizers.py --stop-rules [--evals 5000]``). Hence not the default.
    - ``"none"``: never stops on its own (fixed-budget benchmarks).

    Hyperparameters: pop_size (particles), w (inertia), c1/c2 (cognitive/social
    acceleration), v_max (max speed, fraction of the box per step), crossover_prob, sbx_eta,
    mutation_prob (per variable; default 1/d), pm_eta, and the stop-rule settings above.

    Written by hand (only the glue): no library has the paper's PSO/GA alternation; the PSO
    update (``pso_equation``) and the GA operators are pymoo's.

    >>> opt = PsoGa([0, 0], [1, 1], seed=0, pop_size=6)
    >>> X = opt.ask(); opt.tell(X, (X ** 2).sum(axis=1)); X.shape
    (6, 2)
    """

    def __init__(self, lower, upper, seed: int, x0=None, pop_size: int = 20, w: float = 0.7298,
                 c1: float = 1.49618, c2: float = 1.49618, v_max: float = 0.2,
                 crossover_prob: float = 0.9, sbx_eta: float = 15.0, mutation_prob: float | None = None,
                 pm_eta: float = 20.0, stop_rule: str = "patience", epsilon: float = 1e-3,
                 patience: int = 20, tol: float = 1e-6) -> None:
        from pymoo.algorithms.soo.nonconvex.ga import comp_by_cv_and_fitness
        from pymoo.algorithms.soo.nonconvex.pso import pso_equation
        from pymoo.core.population import Population
        from pymoo.core.problem import Problem
        from pymoo.operators.crossover.sbx import SBX
        from pymoo.operators.mutation.pm import PM
        from pymoo.operators.selection.tournament import TournamentSelection

        super().__init__(lower, upper)  # bounds, ask/tell guards, NaN -> inf, best tracking
        d = self.dim
        self.n = self.int_param("pop_size", pop_size, 2, even=True)
        self.w, self.c1, self.c2 = (self.float_param(k, v, 0) for k, v in (("w", w), ("c1", c1), ("c2", c2)))
        self.v_max = self.float_param("v_max", v_max, 0, low_open=True)
        self.stop_rule = self.choice_param("stop_rule", stop_rule, _STOP_RULES)
        self.epsilon = self.float_param("epsilon", epsilon, 0)
        self.patience = self.int_param("patience", patience, 1)
        self.tol = self.float_param("tol", tol, 0)
        crossover_prob = self.float_param("crossover_prob", crossover_prob, 0, 1)
        sbx_eta = self.float_param("sbx_eta", sbx_eta, 0, low_open=True)
        pm_eta = self.float_param("pm_eta", pm_eta, 0, low_open=True)
        mutation_prob = 1.0 / d if mutation_prob is None else self.float_param("mutation_prob", mutation_prob, 0, 1)
        self.rng = np.random.default_rng(self.seed_param(seed))
        self._Population, self._pso_equation = Population, pso_equation
        self._unit = Problem(n_var=d, n_obj=1, xl=np.zeros(d), xu=np.ones(d))
        self._select = TournamentSelection(func_comp=comp_by_cv_and_fitness, pressure=2)
        self._crossover = SBX(prob=crossover_prob, eta=sbx_eta)
        self._mutation = PM(prob=1.0, prob_var=mutation_prob, eta=pm_eta)

        self._phase = "init"  # what the next ask produces: "init", "pso" or "ga"
        self._asked: np.ndarray | None = None  # last asked batch, normalised (n, d)
        self.u = self.v = self.f = self.pbest_u = self.pbest_f = None
        self.gbest_u, self.gbest_f = np.full(d, np.nan), np.inf
        self._prev_gbest_u: np.ndarray | None = None
        self._f_last_improvement = np.inf  # best f when the patience counter was last reset
        self.iterations, self._stale, self._stop = 0, 0, None

    def _ask(self) -> np.ndarray:
        if self._phase == "init":
            U = self.rng.random((self.n, self.dim))
        elif self._phase == "pso":
            U = self._pso_step()
        else:
            U = self._ga_offspring()
        self._asked = U
        return self.from_unit(U)

    def _tell(self, X: np.ndarray, f: np.ndarray) -> None:
        U, self._asked = self._asked, None
        if self._phase == "init":
            self.u, self.f, self.v = U, f, np.zeros_like(U)
            self.pbest_u, self.pbest_f = U.copy(), f.copy()
            self._update_gbest()
            self._prev_gbest_u, self._f_last_improvement = self.gbest_u.copy(), self.gbest_f
            self._phase = "pso"
        elif self._phase == "pso":
            self.u, self.f = U, f
            self._update_pbest()
            self._phase = "ga"
        else:
            self._keep_best_population(U, f)
            self._phase = "pso"
            self._end_iteration()

    def _pso_step(self) -> np.ndarray:
        v_max = np.full(self.u.shape[1], self.v_max)
        U, V = self._pso_equation(self.u, self.pbest_u, self.gbest_u[None, :], self.v, v_max,
                                  self.w, self.c1, self.c2, random_state=self.rng)
        hit = (U < 0.0) | (U > 1.0)
        self.v = np.where(hit, 0.0, V)  # absorbing walls: a particle that hit the box stops there
        return np.clip(U, 0.0, 1.0)

    def _ga_offspring(self) -> np.ndarray:
        pop = self._Population.new("X", self.u)
        pop.set("F", self.f[:, None], "CV", np.zeros((self.n, 1)))
        parents = self._select.do(self._unit, pop, n_select=self.n // 2, n_parents=2, to_pop=False,
                                  random_state=self.rng).astype(int)  # pymoo returns float indices
        off = self._crossover.do(self._unit, pop, parents, random_state=self.rng)
        off = self._mutation.do(self._unit, off, random_state=self.rng)
        return np.clip(off.get("X"), 0.0, 1.0)

    def _keep_best_population(self, U: np.ndarray, f: np.ndarray) -> None:
        # (μ+λ) truncation written out by slot so each survivor keeps a velocity and a pbest memory
        worst_slots = np.argsort(-self.f, kind="stable")
        best_children = np.argsort(f, kind="stable")
        wins = f[best_children] < self.f[worst_slots]
        slots, children = worst_slots[wins], best_children[wins]
        self.u[slots], self.f[slots] = U[children], f[children]
        self._update_pbest()

    def _update_pbest(self) -> None:
        better = self.f < self.pbest_f
        self.pbest_u[better], self.pbest_f[better] = self.u[better], self.f[better]
        self._update_gbest()

    def _update_gbest(self) -> None:
        i = int(np.argmin(self.pbest_f))
        if self.pbest_f[i] < self.gbest_f:
            self.gbest_u, self.gbest_f = self.pbest_u[i].copy(), float(self.pbest_f[i])

    def _end_iteration(self) -> None:
        self.iterations += 1
        du = self.gbest_u - self._prev_gbest_u
        if self.stop_rule == "paper" and float(du @ du) <= self.epsilon:
            self._stop = f"converged: ΔuᵀΔu = {float(du @ du):.3g} <= epsilon = {self.epsilon:g} (normalised units)"
        self._prev_gbest_u = self.gbest_u.copy()
        f_old = self._f_last_improvement
        if not np.isfinite(f_old) or f_old - self.gbest_f > self.tol * max(abs(f_old), 1e-12):
            self._f_last_improvement, self._stale = self.gbest_f, 0
        else:
            self._stale += 1
        if self.stop_rule == "patience" and self._stale >= self.patience:
            self._stop = f"converged: best f improved by <= {self.tol:g} (relative) for {self.patience} iterations"

    @property
    def stop(self) -> str | None:
        return self._stop
