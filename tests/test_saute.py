"""Sauté RL (algo=saute): the budget state counts down as Sootla et al. (2022) state, the
reward is replaced exactly once a budget is spent, a new episode restores it; and a learning run."""

import json

import pytest
import torch

from cmdp_rl import train
from cmdp_rl.config.run_config import compose_config, load_config
from cmdp_rl.config.validation import ConfigError
from cmdp_rl.envs.saute import BudgetStateEnv
from cmdp_rl.envs.vector import Step, VecEnv


class Scripted(VecEnv):
    """N = 2 envs, K costs per step from a script; reward 1 each step; obs = [step count]. Env 0's
    episode ends (truncated) after ``end_after`` steps, env 1's never."""

    def __init__(self, costs: list[list[list[float]]], end_after: int = 100) -> None:
        self.costs, self.end_after = costs, end_after
        self.num_envs, self.num_costs, self.obs_dim, self.action_dim = 2, len(costs[0][0]), 1, 1
        self.action_low, self.action_high = -torch.ones(1), torch.ones(1)
        self.device = torch.device("cpu")
        self.t = 0

    def reset(self, seed=None):
        self.t = 0
        return torch.zeros(2, 1)

    def step(self, action):
        cost = torch.tensor(self.costs[self.t], dtype=torch.float32)
        self.t += 1
        truncated = torch.tensor([[self.t == self.end_after], [False]])
        obs = torch.full((2, 1), float(self.t))
        return Step(
            next_obs=obs,
            reward=torch.ones(2, 1),
            cost=cost,
            terminated=torch.zeros(2, 1, dtype=torch.bool),
            truncated=truncated,
            obs=obs,
        )

    def state_dict(self):
        return {"t": self.t}

    def load_state_dict(self, state):
        self.t = state["t"]


def close(t: torch.Tensor, expected: list) -> bool:
    return torch.allclose(t, torch.tensor(expected, dtype=t.dtype), atol=1e-6)


def test_the_budget_state_counts_down_and_the_reward_is_replaced_once_spent():
    d, gamma = 2.0, 0.9
    costs = [[[0.5], [0.0]], [[1.0], [0.0]], [[0.6], [3.0]], [[0.0], [0.0]]]
    env = BudgetStateEnv(Scripted(costs), [d], discount=gamma, unsafe_reward=-5.0)
    obs = env.reset()
    assert obs[:, -1].tolist() == [1.0, 1.0]  # z_0 = d, normalised: 1
    z = [1.0, 1.0]
    spent_at = []
    for t, c in enumerate(costs):
        step = env.step(torch.zeros(2, 1))
        z = [(z[i] - c[i][0] / d) / gamma for i in range(2)]  # z_{t+1} = (z_t - c_t / d) / gamma_c
        assert step.next_obs[:, -1].tolist() == pytest.approx(z)
        assert step.next_obs[:, 0].tolist() == [t + 1.0] * 2  # the env's own observation, unchanged
        assert close(step.cost, c)  # costs pass through
        spent = [zi < 0 for zi in z]
        assert step.reward.view(-1).tolist() == [-5.0 if s else 1.0 for s in spent]
        spent_at.append(spent)
    # z_t < 0 <=> sum_{k<t} gamma^k c_k > d. Env 0's costs sum to 2.1 > d, but discounted to
    # 0.5 + 0.9 * 1.0 + 0.81 * 0.6 = 1.886 <= d: never spent. Env 1's 3.0 at step 2: 2.43 > d.
    assert [s[0] for s in spent_at] == [False, False, False, False]
    assert [s[1] for s in spent_at] == [False, False, True, True]


def test_the_budget_is_spent_exactly_when_the_episode_cost_exceeds_it_and_a_new_episode_restores_it():
    costs = [[[0.5, 0.0], [0.0, 0.0]], [[0.5, 0.0], [0.0, 0.2]], [[0.1, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]]
    env = BudgetStateEnv(Scripted(costs, end_after=3), [1.0, 0.1], unsafe_reward=0.0)  # K = 2, gamma_c = 1
    env.reset()
    s1, s2 = env.step(torch.zeros(2, 1)), env.step(torch.zeros(2, 1))
    assert close(s1.next_obs[:, 1:], [[0.5, 1.0], [1.0, 1.0]])
    assert close(s2.next_obs[:, 1:], [[0.0, 1.0], [1.0, -1.0]])  # env 0: exactly d, not over
    assert s2.reward.view(-1).tolist() == [1.0, 0.0]  # env 1: its second budget is spent
    s3 = env.step(torch.zeros(2, 1))  # env 0 goes over (1.1 > 1) on the step its episode ends
    assert s3.reward.view(-1).tolist() == [0.0, 0.0]
    assert s3.next_obs[0, 1:].tolist() == pytest.approx([-0.1, 1.0])  # the final state keeps its z
    assert close(s3.obs[:, 1:], [[1.0, 1.0], [1.0, -1.0]])  # the new episode: full budget
    saved = env.state_dict()
    assert env.reset()[:, 1:].tolist() == [[1.0, 1.0], [1.0, 1.0]]  # reset restores every budget
    env.load_state_dict(saved)
    assert close(env.z, [[1.0, 1.0], [1.0, -1.0]])
    evaluation = BudgetStateEnv(Scripted(costs), [0.1, 0.1], reshape_reward=False)  # eval: the task's reward
    evaluation.reset()
    assert evaluation.step(torch.zeros(2, 1)).reward.view(-1).tolist() == [1.0, 1.0]


def test_bad_options_are_one_line_config_errors():
    with pytest.raises(ConfigError, match=r"^algo.cost_limit must be > 0 with algo=saute"):
        load_config({"algo": {"name": "saute", "cost_limit": 0.0}})
    with pytest.raises(ConfigError, match=r"^algo.base must be one of \('ppo',\), got 'cpo'$"):
        load_config({"algo": {"name": "saute", "base": "cpo"}})
    with pytest.raises(ConfigError, match=r"^algo.budget_discount must be in \(0, 1\], got 0.0$"):
        load_config({"algo": {"name": "saute", "budget_discount": 0.0}})


@pytest.mark.slow  # a learning run (pyproject: markers)
def test_saute_learns_reach1d_within_budget(tmp_path):
    """Reach1D, passable wall, budget 0.5: any crossing (cost 1) spends the budget, so the almost
    surely safe policy walks up to the wall and stops short of it. Measured on seed 0: the first
    iteration's return is 0.02; the final policy's eval return 0.30 at cost 0 (every episode)."""
    cfg = compose_config(
        [
            "env=reach1d_torch",
            "env.wall=pass",
            "env.num_envs=256",
            "algo=saute",
            "algo.cost_limit=0.5",
            "total_steps=327680",
            "log_interval=1",
            "seed=0",
        ]
    )
    result = train(cfg, tmp_path, echo=lambda s: None)
    assert result["episode_cost"] <= 0.5, result["episode_cost"]
    assert result["episode_return"] >= 0.2, result["episode_return"]  # the initial policy's: 0.02


def test_evaluate_py_rebuilds_the_augmented_env_and_repeats_eval_json(tmp_path):
    """evaluate.py builds its env through make_eval_env with the run's algo options, so a Sauté
    policy (observation + budget) evaluates as it did in training."""
    from helpers.runs import eval_result, tiny

    from cmdp_rl.cli import evaluate as evaluate_cli

    cfg = tiny(total_steps=64, algo={"name": "saute", "update_epochs": 2, "num_minibatches": 2, "cost_limit": 0.5})
    del cfg["algo"]["multiplier"]
    train(load_config(cfg), tmp_path, echo=lambda s: None)
    out = tmp_path / "e.json"
    assert evaluate_cli.main([f"run={tmp_path}", f"output={out}"]) == 0
    got, want = json.loads(out.read_text()), eval_result(tmp_path)
    same = [f"episode_{m}{s}" for m in ("return", "cost", "length") for s in ("", "_std", "_min", "_max")]
    assert {k: got[k] for k in same} == {k: want[k] for k in same}
