"""Multi-agent CMDPs: env=pettingzoo (agents as rows of the batch), the team-work CMDP's exact
optimum, the contract naming a broken agent, and algo=mappo_lag (team and per-agent budgets):
it trains to within the budget and 10% of the optimum, and resumes exactly."""

import numpy as np
import pytest
import torch
from helpers.runs import eval_result, metrics_rows
from pettingzoo.test import parallel_api_test

from cmdp_rl import load_config, train
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.envs import EnvContractError, check_env, make_env
from cmdp_rl.envs.multi_agent import PettingZooVecEnv
from cmdp_rl.envs.team_work import TeamWork, constrained_optimum
from cmdp_rl.policies.agent import make_agent
from cmdp_rl.run.checkpoint import load_checkpoint

WORK, SPRINT, IDLE = 1, 2, 0


def test_team_work_is_a_pettingzoo_parallel_env():
    parallel_api_test(TeamWork(), num_cycles=30)


@pytest.mark.parametrize(
    "budget, optimum",
    [
        (10.0, 25.0),  # both work every step: 2.5 a step at cost 1
        ([5.0, 5.0], 25.0),  # the same, one budget per agent
        (15.0, 27.5),  # 1.5 a step: half the steps one also sprints (3 at cost 2), by hand
        (1000.0, 35.0),  # unconstrained: both sprint
        (0.0, 0.0),  # no strain allowed: both idle
    ],
)
def test_exact_optimum_by_hand(budget, optimum):
    value, policy = constrained_optimum(budget)
    assert value == pytest.approx(optimum, abs=1e-9)
    if budget == 10.0:  # the optimum is deterministic: both work at every step
        assert np.allclose(policy[:, WORK, WORK], 1.0)


def test_agents_are_rows_with_own_part_id_and_every_agents_observation():
    env = PettingZooVecEnv(TeamWork, num_envs=2)
    assert env.num_envs == 4 and env.agents_per_env == 2 and env.actor_obs_dim == 1 + 2 and env.obs_dim == 5
    obs = env.reset(seed=0)
    assert obs[1].tolist() == [0.0, 0.0, 1.0, 0.0, 0.0]  # env 0, agent 1: own t, id, both t
    # env 0: worker_0 sprints, worker_1 works; env 1: both idle
    step = env.step(torch.tensor([[SPRINT], [WORK], [IDLE], [IDLE]]))
    assert step.reward.squeeze(-1).tolist() == [3.0, 3.0, 0.0, 0.0]  # the team reward to every agent
    assert step.cost.squeeze(-1).tolist() == [2.0, 2.0, 0.0, 0.0]  # the team's strain on every row
    assert env.cost_names == ("strain",)
    env.constraint = "per_agent"
    assert env.cost_names == ("worker_0/strain", "worker_1/strain")
    step = env.step(torch.tensor([[SPRINT], [WORK], [IDLE], [IDLE]]))
    assert step.cost.tolist() == [[1.5, 0.5], [1.5, 0.5], [0.0, 0.0], [0.0, 0.0]]
    saved = env.state_dict()
    for _ in range(8):  # to the horizon: every row of an env ends together, terminated
        step = env.step(torch.ones(4, 1, dtype=torch.int64))
    assert step.terminated.all() and not step.truncated.any() and step.obs[:, 0].eq(0).all()
    env.load_state_dict(saved)
    assert env.step(torch.ones(4, 1, dtype=torch.int64)).next_obs[0, 0].item() == pytest.approx(0.3)


class BrokenTeam(TeamWork):
    """worker_1 reports a negative cost on its third step."""

    def step(self, actions):
        out = super().step(actions)
        if self.t == 3:
            out[4]["worker_1"]["cost"] = -1.0
        return out


def test_the_contract_names_the_broken_agent_in_one_line(tmp_path, quiet):
    cfg = load_config({"env": {"name": "pettingzoo", "factory": "test_multi_agent:BrokenTeam"}})
    with pytest.raises(EnvContractError) as err:
        check_env(make_env(cfg.env, num_envs=2))
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(
        "env test_multi_agent:BrokenTeam agent 'worker_1' (env 0, step 3): info[\"cost\"] is -1.0"
    )
    with pytest.raises(EnvContractError, match="agent 'worker_1'"):
        train(load_config({"env": {"name": "pettingzoo", "factory": "test_multi_agent:BrokenTeam"}}), tmp_path)
    assert not (tmp_path / "metrics.csv").exists()


@pytest.mark.parametrize(
    "override, message",
    [
        (
            {"env": {"name": "pettingzoo", "factory": "no_such_module:make"}},
            "env.factory: cannot import 'no_such_module'",
        ),
        ({"env": {"name": "pettingzoo", "factory": "cmdp_rl.envs.team_work:Nope"}}, "has no callable 'Nope'"),
        ({"env": {"name": "pettingzoo", "factory": "no colon"}}, "env.factory must"),
        ({"env": {"name": "skills"}, "algo": {"name": "mappo_lag"}}, "env must be pettingzoo with algo=mappo_lag"),
        (
            {"env": {"name": "pettingzoo"}, "algo": {"name": "mappo_lag", "constraint": "both"}},
            "algo.constraint must be one of",
        ),
        ({"env": {"name": "pettingzoo"}, "algo": {"name": "mappo_lag"}, "policy": {"name": "lstm"}}, "policy.name"),
    ],
)
def test_bad_options_are_one_line(tmp_path, quiet, override, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")) as err:
        train(load_config({**override, "total_steps": 64}), tmp_path, echo=quiet)
    assert "\n" not in str(err.value)


def test_the_actor_reads_its_own_part_and_the_critics_every_agents():
    cfg = load_config({"env": {"name": "pettingzoo", "num_envs": 2}})
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env)
    obs = env.reset(seed=0)
    changed = obs.clone()
    changed[:, env.actor_obs_dim :] += 1.0  # every agent's observations, not the row's own part
    assert torch.equal(
        agent.actor.params({"observation": obs})["logits"], agent.actor.params({"observation": changed})["logits"]
    )
    assert not torch.equal(agent.value("reward", {"observation": obs}), agent.value("reward", {"observation": changed}))


MAPPO = {
    "env": {"name": "pettingzoo"},
    "algo": {"name": "mappo_lag", "cost_limit": 10.0},
    "total_steps": 40 * 1024,
    "eval_episodes": 20,
}


def test_mappo_lag_reaches_the_exact_optimum_within_budget(tmp_path, quiet):
    """Seeded; team budget 10 (1 a step). The exact optimum is 25 (both work); reward alone would
    make both sprint (35 at cost 30). Greedy evaluation: within the budget and 10% of 25."""
    lines = []
    result = train(load_config(MAPPO), tmp_path, echo=lines.append)
    optimum = TeamWork.optimum(10.0)
    assert result["episode_cost"] <= 10.0
    assert result["episode_return"] >= 0.9 * optimum
    assert any("constrained optimum 25.000 (exact solver)" in line for line in lines)


def test_per_agent_budgets_have_one_multiplier_each(tmp_path, quiet):
    cfg = {
        "env": {"name": "pettingzoo", "num_envs": 2},
        "algo": {"name": "mappo_lag", "constraint": "per_agent", "cost_limit": [5.0, 4.0]},
        "rollout_steps": 20,
        "total_steps": 2 * 80,
        "eval_episodes": 3,
    }
    result = train(load_config(cfg), tmp_path, echo=quiet)
    row = metrics_rows(tmp_path)[-1]
    for agent, budget in (("worker_0", 5.0), ("worker_1", 4.0)):
        assert float(row[f"cost_limit/{agent}/strain"]) == budget and f"lagrange_multiplier/{agent}/strain" in row
        assert result[f"cost_limit/{agent}/strain"] == budget and f"episode_cost/{agent}/strain" in result


def test_evaluation_counts_a_teams_episode_once(tmp_path, quiet):
    cfg = {"env": {"name": "pettingzoo", "num_envs": 2}, "rollout_steps": 20, "total_steps": 80, "eval_episodes": 5}
    result = train(load_config(cfg), tmp_path, echo=quiet)
    assert result["episodes"] == 5


def test_mappo_lag_resume_is_exact(tmp_path, quiet):
    cfg = {
        "env": {"name": "pettingzoo", "num_envs": 2},
        "algo": {"name": "mappo_lag", "update_epochs": 2, "num_minibatches": 2, "multiplier": {"lr": 0.5}},
        "rollout_steps": 15,  # not a multiple of the horizon: episodes run across iterations
        "total_steps": 6 * 60,
        "checkpoint_every": 2,
        "eval_episodes": 4,
    }
    long, short = tmp_path / "long", tmp_path / "short"
    train(load_config(cfg), long, echo=quiet)
    train(load_config({**cfg, "total_steps": 3 * 60}), short, echo=quiet)
    train(load_config({**cfg, "resume": str(short)}), echo=quiet)
    assert metrics_rows(long) == metrics_rows(short) and eval_result(long) == eval_result(short)
    a, b = (load_checkpoint(d / "checkpoint.pt")["members"][0] for d in (long, short))
    assert all(
        torch.equal(a["algo_state"]["networks"][k], b["algo_state"]["networks"][k]) for k in a["algo_state"]["networks"]
    )
    assert a["algo_state"]["multiplier"] == b["algo_state"]["multiplier"]


def test_safety_mamujoco_2x3_halfcheetah_steps_with_each_agents_cost():
    """Safety-Gymnasium's multi-agent velocity task through compat.py and the adapter: the contract
    holds, each agent's velocity cost reaches the rows, the time limit truncates, and the state
    restores exactly."""
    from cmdp_rl.envs.safety_gym.multi_agent import SafetyMaMuJoCo

    env = PettingZooVecEnv(lambda: SafetyMaMuJoCo("HalfCheetah", "2x3", max_steps=12), num_envs=2)
    assert env.agents == ["agent_0", "agent_1"] and env.action_dim == 3 and env.actor_obs_dim == 12 + 2
    assert check_env(env, steps=15).cost_names == ("velocity",)
    env.constraint = "per_agent"
    env.reset(seed=0)
    torch.manual_seed(0)
    for _ in range(4):
        env.step(torch.rand(4, 3) * 2 - 1)
    saved = env.state_dict()
    first = [env.step(torch.full((4, 3), 0.7)) for _ in range(3)]
    env.load_state_dict(saved)
    again = [env.step(torch.full((4, 3), 0.7)) for _ in range(3)]
    for a, b in zip(first, again):
        assert torch.equal(a.next_obs, b.next_obs) and torch.equal(a.reward, b.reward)
    assert first[0].cost.shape == (4, 2) and torch.equal(first[0].reward[0], first[0].reward[1])  # team reward
    for _ in range(5):  # steps 8..12: the time limit ends every team's episode at step 12
        step = env.step(torch.zeros(4, 3))
    assert step.truncated.all() and not step.terminated.any()


class TwoCostTeam(TeamWork):
    """Each agent reports K = 2 costs: its strain and a flag for sprinting."""

    cost_names = None  # found from the info, named cost_0, cost_1

    def step(self, actions):
        out = super().step(actions)
        for a, info in out[4].items():
            info["cost"] = np.array([info["cost"], float(int(actions[a]) == SPRINT)])
        return out


class MismatchedTeam(TeamWork):
    """worker_1 reports two costs, worker_0 one."""

    def step(self, actions):
        out = super().step(actions)
        out[4]["worker_1"]["cost"] = [1.0, 0.0]
        return out


def test_k_costs_per_agent_sum_for_the_team_or_stay_per_agent():
    env = PettingZooVecEnv(TwoCostTeam, num_envs=1)
    assert env.cost_names == ("cost_0", "cost_1") and check_env(env).num_costs == 2
    env.reset(seed=0)
    assert env.step(torch.tensor([[SPRINT], [WORK]])).cost.tolist() == [[2.0, 1.0], [2.0, 1.0]]
    env.constraint = "per_agent"
    assert env.cost_names == ("worker_0/cost_0", "worker_0/cost_1", "worker_1/cost_0", "worker_1/cost_1")
    assert env.step(torch.tensor([[SPRINT], [WORK]])).cost[0].tolist() == [1.5, 1.0, 0.5, 0.0]
    with pytest.raises(EnvContractError, match="agents report different numbers of costs"):
        check_env(PettingZooVecEnv(MismatchedTeam, num_envs=1))
