"""A new algorithm and a new env, defined in this file alone, trained through ``train()``.

This is the worked example of ``docs/architecture.md`` ("Add an algorithm", "Add an env"): nothing
in ``cmdp_rl`` knows the names ``toy_reinforce`` or ``toy_target``. Each component declares its
options (``cmdp_rl.config.validation.options``) and registers itself (``cmdp_rl.config.registry.register``);
the trainer builds them, logs the statistics the algorithm declares, checkpoints, resumes and
evaluates them like any built-in one.
"""

from __future__ import annotations

import csv
import json
import re
from functools import partial
from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers.runs import ROOT, eval_result, metrics_rows
from tensordict import TensorDictBase

from cmdp_rl import ConfigError, evaluate, keys, load_config, make_agent, make_env, train
from cmdp_rl.algos.base import AlgoConfig, check_finite
from cmdp_rl.algos.minibatch import minibatches
from cmdp_rl.algos.ppo import CriticRegression
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import PositiveFloat, PositiveInt, options
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.vector import GymVecEnv, VecEnv
from cmdp_rl.policies.agent import Agent
from cmdp_rl.report.metrics import MetricsLogger
from cmdp_rl.rollout.advantages import TwinGAE


# --- A toy env: a gymnasium env that reports its cost in info["cost"] ----------------------------
class TargetEnv(gym.Env):
    """Each episode draws a target in [-1, 1], shown as the observation; the action should land on
    it. Reward ``-(a - target)^2`` per step; the episode terminates when ``|a - target| < 0.1``, or
    is truncated after ``max_steps``. Cost 1 on a step whose action is beyond 0.5 (a hazard)."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, max_steps: int = 4) -> None:
        self.max_steps = max_steps
        self.target = 0.0
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.target = float(self.np_random.uniform(-1.0, 1.0))
        self.t = 0
        return np.array([self.target], np.float32), {}

    def step(self, action):
        a = float(np.clip(action[0], -1.0, 1.0))
        self.t += 1
        miss = abs(a - self.target)
        obs = np.array([self.target], np.float32)
        return obs, -(miss**2), miss < 0.1, self.t >= self.max_steps, {"cost": float(a > 0.5)}


@options
class TargetEnvConfig(EnvOptions):
    """``env=toy_target``: options checked before anything is built."""

    name: str = "toy_target"
    num_envs: PositiveInt = 4
    max_steps: PositiveInt = 4
    # Evaluation reports the fraction of episodes that terminated, under this name.
    termination_metric: ClassVar[str] = "on_target"


def make_target_env(cfg: TargetEnvConfig, num_envs: int, device: str = "cpu") -> VecEnv:
    return GymVecEnv(partial(TargetEnv, max_steps=cfg.max_steps), num_envs, device=device)


register("env", "toy_target", TargetEnvConfig, make_target_env)


# --- A toy algorithm: REINFORCE with a learned baseline -----------------------------------------
@options
class ReinforceConfig(AlgoConfig):
    """REINFORCE with a baseline (Williams, 1992): one policy-gradient step per batch on
    ``log pi(a|s) * A``, ``A`` the reward GAE (``gae_lambda = 1``: the return minus the baseline)."""

    name: str = "toy_reinforce"
    lr: PositiveFloat = 0.01
    critic_minibatches: PositiveInt = 2


class Reinforce:
    name = "toy_reinforce"
    stats = ("loss_pi", "loss_v", "loss_vc", "entropy")  # metrics.csv's columns besides the run's

    def __init__(self, cfg: ReinforceConfig, agent: Agent) -> None:
        self.cfg, self.agent = cfg, agent
        self.gae = TwinGAE(cfg.gamma, cfg.cost_gamma, cfg.gae_lambda)
        self.critics = CriticRegression(agent)
        self.actor_opt = torch.optim.Adam(agent.actor.parameters(), lr=cfg.lr)
        self.critic_opt = torch.optim.Adam(agent.critics.parameters(), lr=cfg.critic_lr)

    def policy_loss(self, units: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        dist = self.agent.dist(units)
        log_prob = dist.log_prob(units[keys.ACTION])
        adv = units[keys.ADVANTAGE].reshape(log_prob.shape)
        return -(log_prob * adv).mean(), {"entropy": dist.entropy().mean().detach()}

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        self.gae(batch, self.agent)  # values, advantages, value targets of both critics
        adv = batch.get(keys.ADVANTAGE)
        if self.cfg.normalize_advantage:
            batch.set(keys.ADVANTAGE, (adv - adv.mean()) / (adv.std() + 1e-8))
        wanted = [keys.ACTION, keys.ADVANTAGE, *self.critics.target_keys(), *self.agent.in_keys]
        units = self.agent.training_units({k: batch.get(k) for k in wanted})

        loss_pi, stats = self.policy_loss(units)
        self.actor_opt.zero_grad()
        loss_pi.backward()
        self.actor_opt.step()
        critic = {}
        for _, mb in minibatches(units, self.cfg.critic_minibatches):
            losses = self.critics.losses(mb)
            self.critic_opt.zero_grad()
            sum(losses.values()).backward()
            self.critic_opt.step()
            critic = {k: v.item() for k, v in losses.items()}  # the last minibatch's
        out = {"loss_pi": loss_pi.item(), **critic, **{k: v.item() for k, v in stats.items()}}
        check_finite(**out)
        return {**out, "lagrange_multiplier": 0.0}

    def state_dict(self) -> dict:
        return {
            "networks": self.agent.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["networks"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])


register("algo", "toy_reinforce", ReinforceConfig, Reinforce)


class Leaky(Reinforce):
    """Returns a statistic it does not declare."""

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        return {**super().update(batch), "surprise": 1.0}


# --- The tests -------------------------------------------------------------------------------
def toy(**overrides) -> dict:
    cfg = {
        "env": {"name": "toy_target", "num_envs": 4, "max_steps": 4},
        "algo": {"name": "toy_reinforce", "gae_lambda": 1.0, "cost_limit": 0.5},
        "policy": {"name": "mlp", "hidden_sizes": [16]},
        "rollout_steps": 16,
        "total_steps": 6 * 64,
        "checkpoint_every": 2,
        "eval_episodes": 8,
        "log_interval": 1,
    }
    for k, v in overrides.items():
        cfg[k] = {**cfg[k], **v} if isinstance(v, dict) else v
    return cfg


# Written out rather than imported from metrics.py: the run's own columns, the algorithm's declared
# stats in its order, the safety metrics.
EXPECTED_COLUMNS = [
    "iteration",
    "step",
    "episode_return",
    "episode_cost",
    "episode_length",
    "episodes",
    "lagrange_multiplier",
    "cost_limit",
    "sps",
    "time_s",
    "loss_pi",
    "loss_v",
    "loss_vc",
    "entropy",
    "cost_rate",
    "normalized_return",
    "normalized_violation",
    "normalized_cost_rate",
]


def test_toy_algorithm_and_env_train_through_train(tmp_path):
    out, said = tmp_path / "run", []
    result = train(load_config(toy()), out, echo=said.append)
    assert said[0].startswith("training toy_reinforce on toy_target (4 envs): 6 iterations of 64 steps")
    with open(out / "metrics.csv") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    assert reader.fieldnames == EXPECTED_COLUMNS
    assert [r["iteration"] for r in rows] == [str(i) for i in range(1, 7)]
    assert [int(r["step"]) for r in rows] == [64 * i for i in range(1, 7)]
    assert all(r["loss_pi"] and r["entropy"] and r["loss_vc"] for r in rows)  # declared stats are written
    assert all(float(r["cost_limit"]) == 0.5 for r in rows)
    saved = json.loads((out / "eval.json").read_text())
    assert saved["episodes"] == 8 and saved == json.loads(json.dumps(result))
    assert 0.0 <= saved["on_target"] <= 1.0  # the env's termination metric, under the env's name
    assert "goal_reached" not in saved
    assert (out / "checkpoint.pt").is_file() and (out / "config.yaml").is_file()


def test_undeclared_stat_is_an_error_not_dropped(tmp_path, quiet):
    # Registered here, not at import: the algorithms registered when tests are collected all join
    # the cross-cutting tests (test_registry_enrolment.py), and this one is broken on purpose.
    register("algo", "toy_leaky", ReinforceConfig, Leaky)
    with pytest.raises(ValueError, match=r"\['surprise'\] are not columns"):
        train(load_config(toy(algo={"name": "toy_leaky"})), tmp_path / "run", echo=quiet)


@pytest.mark.parametrize(
    "override,message",
    [
        ({"algo": {"lr": 0}}, "algo.lr must be a positive number, got 0"),
        ({"algo": {"critic_minibatches": 1.5}}, "algo.critic_minibatches must be a positive integer, got 1.5"),
        ({"env": {"max_steps": -3}}, "env.max_steps must be a positive integer, got -3"),
        (
            {"algo": {"lr_typo": 1}},
            "algo: unknown option(s) ['lr_typo']; allowed: ['cost_gamma', 'cost_limit', "
            "'critic_lr', 'critic_minibatches', 'gae_lambda', 'gamma', 'lr', 'max_grad_norm', 'name', "
            "'normalize_advantage']",
        ),
    ],
)
def test_bad_option_is_a_one_line_config_error(override, message):
    with pytest.raises(ConfigError) as err:
        load_config(toy(**override))
    assert str(err.value) == message  # train.py prints "config error: " + this


def test_toy_run_resumes_to_the_same_numbers(tmp_path, monkeypatch, quiet):
    whole, broken = tmp_path / "whole", tmp_path / "broken"
    train(load_config(toy()), whole, echo=quiet)
    original = MetricsLogger.log

    def crash_after_5(self, row, force_echo=False, **kwargs):
        original(self, row, force_echo, **kwargs)
        if row["iteration"] == 5:
            raise KeyboardInterrupt

    monkeypatch.setattr(MetricsLogger, "log", crash_after_5)
    with pytest.raises(KeyboardInterrupt):
        train(load_config(toy()), broken, echo=quiet)
    monkeypatch.undo()
    assert len(metrics_rows(broken)) == 5  # the checkpoint is at iteration 4: row 5 is redone
    train(load_config({**toy(), "resume": str(broken)}), echo=quiet)
    assert metrics_rows(broken) == metrics_rows(whole)
    assert eval_result(broken) == eval_result(whole)


@pytest.mark.slow  # a learning run (pyproject: markers)
def test_toy_algorithm_learns_the_toy_env(tmp_path, quiet):
    """Untrained, the policy's mean action is about 0: on target (within 0.1) for about 10% of the
    uniform targets, return about -4/3 (4 steps of E[target^2] = 1/3 for most episodes). Trained
    (60 iterations, 3840 steps), it tracks the target. Measured at seeds 0-3: return -0.003, -0.003,
    -0.02, -0.07 and on-target 1.0, 1.0, 0.68, 0.48 (seed 0 here)."""
    cfg = load_config(toy(total_steps=60 * 64, eval_episodes=40, checkpoint_every=100))
    torch.manual_seed(cfg.seed)
    untrained = evaluate(
        make_agent(cfg.policy, make_env(cfg.env)), make_env(cfg.env), 40, seed=1, termination_metric="on_target"
    )
    trained = train(cfg, tmp_path / "run", echo=quiet)
    assert untrained["on_target"] <= 0.25 and untrained["episode_return"] < -1.0
    assert trained["on_target"] >= 0.4
    assert trained["episode_return"] > -0.1


def test_architecture_doc_shows_this_files_code():
    """docs/architecture.md's "Add an algorithm" and "Add an env" are copied from this file: every
    python block there must appear here verbatim, so the doc cannot drift from code that runs."""
    doc = (ROOT / "docs" / "architecture.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", doc, flags=re.S)
    assert len(blocks) == 2
    here = (ROOT / "tests" / "test_components.py").read_text()
    for block in blocks:
        assert block in here, block[:200]
