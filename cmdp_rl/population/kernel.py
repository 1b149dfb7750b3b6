"""A population's kernel (:class:`StackedKernel`, a ``run.kernel.Kernel``): P agents, each built, seeded and
budgeted as its single run builds it, trained as one tensor program (``stacked.py``, ``learner.py``) in one env of
P N rows (``envs.py``); the run's loop, opening and checkpoint drive it as they drive a run's one agent."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase

from cmdp_rl.config.run_config import RunConfig
from cmdp_rl.config.saved import POPULATION_CHECKPOINT
from cmdp_rl.population.envs import population_env
from cmdp_rl.population.learner import StackedLearner
from cmdp_rl.population.spec import stacked
from cmdp_rl.population.stacked import PopulationAgent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.run.checkpoint import member_entry
from cmdp_rl.run.evaluation import EVAL_SEED_OFFSET, MODES, evaluate_members, mode_name
from cmdp_rl.run.kernel import restore
from cmdp_rl.run.migrations import population_from_stacked
from cmdp_rl.run.start import build_run


class StackedKernel:
    """P agents on the stacked program: each agent's networks and algorithm state as its single run builds them,
    under its seed, and the generator it then has (where its single run's action samples and permutations
    start); their envs, acting and update as one. Each agent's costs so far are counted here (``costs``)."""

    def __init__(self, cfgs: list[RunConfig], device: torch.device) -> None:
        self.agents, self.algos, self.generators = [], [], []
        for c in cfgs:
            probe, agent, algo = build_run(c)
            probe.close()
            self.agents.append(agent)
            self.algos.append(algo)
            g = torch.Generator(device=device)
            g.set_state(torch.get_rng_state() if device.type == "cpu" else torch.cuda.get_rng_state(device))
            self.generators.append(g)
        cfg, self.P = cfgs[0], len(cfgs)
        self.env = population_env(cfgs, cfg.env.num_envs, [c.seed for c in cfgs], device)
        self.agent = PopulationAgent(self.agents, self.generators, device)
        self.learner = StackedLearner(self.agent, self.algos, stacked(cfg.algo.name, getattr(cfg.algo, "base", None)))
        self.collector = Collector(self.env, self.agent, cfg.rollout_steps, seed=None)
        self.per_iter = cfg.rollout_steps * cfg.env.num_envs  # steps per agent
        self.costs = torch.zeros(self.P, len(self.env.cost_names), dtype=torch.float64)  # each agent's so far

    def restore(self, state: dict[str, Any], saved_cfgs: list[dict]) -> dict[str, Any]:
        if "members" not in state:  # the stacked layout of earlier populations
            fresh = [member_entry(r, a) for r, a in zip(saved_cfgs, self.algos)]
            modules = {"actor": self.agents[0].actor, "critics": self.agents[0].critics}
            state = population_from_stacked(state, fresh, modules)
        restore(state, self.algos, self.collector)  # each agent as its run resumes
        self.learner.transfer(to_agents=False)
        for g, s in zip(self.generators, state["rng"]["generators"]):
            g.set_state(s)
        # a list of P before K costs
        self.costs = torch.as_tensor(state["costs"], dtype=torch.float64).view(self.P, len(self.env.cost_names))
        return state

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        return self.learner.update(batch)

    def cost_totals(self, batch: TensorDictBase | None = None) -> list[list[float]]:
        """Each agent's costs so far, ``batch``'s included."""
        if batch is not None:
            costs = batch.get((keys.NEXT, keys.COST)).reshape(self.P, -1, self.costs.shape[1]).sum(1)
            self.costs = self.costs + costs.to(self.costs)
        return self.costs.tolist()

    def rng(self) -> dict[str, Any]:
        return {"generators": [g.get_state() for g in self.generators]}

    def sync_agents(self) -> None:
        """The stacked rows into each agent's own objects (its ``state_dict`` its single run's)."""
        self.learner.transfer(to_agents=True)

    def sync_actors(self) -> None:
        self.learner.copy_actors(to_modules=True)

    def checkpoint_extras(self) -> dict[str, Any]:
        return {"costs": self.costs}

    def after_checkpoint(self, path: Path) -> None:
        (path.parent / POPULATION_CHECKPOINT).unlink(missing_ok=True)  # an older population's, now superseded

    def evaluate(self, cfgs: list[RunConfig], device: torch.device) -> list[dict[str, Any]]:
        """Each agent's single-run evaluation in both modes (``evaluation.both_modes``), side by side."""
        self.learner.copy_actors(to_modules=False)  # the deployed actors (an average) into the stacked rows
        per_mode = {name: self._evaluate_mode(cfgs, device, det) for name, det in MODES.items()}
        head = mode_name(cfgs[0].eval_deterministic)
        return [{**per_mode[head][k], "modes": {n: r[k] for n, r in per_mode.items()}} for k in range(len(cfgs))]

    def _evaluate_mode(self, cfgs: list[RunConfig], device: torch.device, deterministic: bool) -> list[dict[str, Any]]:
        """min(eval_episodes, num_envs) envs per agent, seeded with its evaluation seed, which also seeds its
        action samples."""
        cfg = cfgs[0]
        seeds = [c.seed + EVAL_SEED_OFFSET for c in cfgs]
        eval_env = population_env(cfgs, min(cfg.eval_episodes, cfg.env.num_envs), seeds, device, evaluation=True)
        self.agent.generators = [torch.Generator(device=device).manual_seed(s) for s in seeds]
        limits = [c.algo.cost_limit for c in cfgs]
        try:
            return evaluate_members(
                self.agent, eval_env, cfg.eval_episodes, deterministic, limits, cfg.env.termination_metric
            )
        finally:
            self.agent.generators = self.generators
            eval_env.close()
