"""Discrete and MultiDiscrete actions end to end: the distributions (hand-computed), the previous
action's encoding, the gymnasium vector env, the collector, CPO's Fisher-vector product on a
categorical KL, every registered algorithm x every policy head on MultiDiscrete actions
(tests/helpers/cost_envs.py) and, for those that take K > 1 costs, on Discrete actions with two costs
(env=grid), a learning check, checkpoints and evaluation, and ``train.py env=gym`` on a discrete env."""

import csv
import json
import math
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers import cost_envs
from helpers.runs import ROOT
from torch.distributions import kl_divergence

from cmdp_rl import keys, load_config, train
from cmdp_rl.algos.base import AlgoConfig
from cmdp_rl.algos.trust_region.cpo import fisher_vector_product
from cmdp_rl.config.registry import component, names
from cmdp_rl.config.run_config import CONFIG_DIR, ConfigError
from cmdp_rl.envs import GymVecEnv, make_cost_env
from cmdp_rl.policies import make_agent
from cmdp_rl.policies.distributions import Categorical, CategoricalHead, MultiCategorical, make_action_head
from cmdp_rl.policies.inputs import InputEncoder
from cmdp_rl.rollout.actions import UnsupportedActionSpace, action_dim, check_action_space, to_env
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.run.evaluation import evaluate
from cmdp_rl.run.rundir import load_trained

log = math.log


# --- distributions -------------------------------------------------------------------------------
def test_multi_categorical_log_prob_entropy_mode_by_hand():
    # components: probs (1/4, 3/4) and (1/4, 1/4, 1/2)
    logits = torch.tensor([[log(1), log(3), log(1), log(1), log(2)]])
    d = MultiCategorical(logits, (2, 3))
    assert d.log_prob(torch.tensor([[1, 2]])).item() == pytest.approx(log(0.75) + log(0.5), abs=1e-6)
    assert d.log_prob(torch.tensor([[0, 1]])).item() == pytest.approx(log(0.25) + log(0.25), abs=1e-6)
    h = -(0.25 * log(0.25) + 0.75 * log(0.75)) - (2 * 0.25 * log(0.25) + 0.5 * log(0.5))
    assert d.entropy().item() == pytest.approx(h, abs=1e-6)
    assert d.deterministic_sample.tolist() == [[1, 2]]
    assert d.batch_shape == (1,) and d.event_shape == (2,)


def test_multi_categorical_kl_is_the_sum_of_the_components():
    p = MultiCategorical(torch.tensor([log(1), log(3), log(1), log(1), log(2)]), (2, 3))
    q = MultiCategorical(torch.tensor([log(1), log(1), log(2), log(1), log(1)]), (2, 3))
    # KL((1/4, 3/4) || (1/2, 1/2)) + KL((1/4, 1/4, 1/2) || (1/2, 1/4, 1/4))
    want = (0.25 * log(0.25 / 0.5) + 0.75 * log(0.75 / 0.5)) + (0.25 * log(0.25 / 0.5) + 0 + 0.5 * log(0.5 / 0.25))
    assert kl_divergence(p, q).item() == pytest.approx(want, abs=1e-6)
    assert kl_divergence(p, p).item() == pytest.approx(0.0, abs=1e-7)


def test_multi_categorical_samples_each_component_with_its_probabilities():
    torch.manual_seed(0)
    d = MultiCategorical(torch.tensor([log(1), log(3), log(1), log(1), log(2)]).expand(20000, 5), (2, 3))
    s = d.sample()
    assert s.shape == (20000, 2) and s.dtype == torch.int64
    assert (s[:, 0] == 1).float().mean().item() == pytest.approx(0.75, abs=0.015)
    assert (s[:, 1] == 2).float().mean().item() == pytest.approx(0.5, abs=0.015)


def test_categorical_stores_indices_as_one_column_and_its_mode_is_the_argmax():
    d = Categorical(logits=torch.tensor([[0.0, 2.0, 1.0], [3.0, 0.0, 0.0]]))
    assert d.sample().shape == (2, 1)
    assert d.deterministic_sample.tolist() == [[1], [0]]
    p = torch.softmax(torch.tensor([0.0, 2.0, 1.0]), -1)
    assert d.log_prob(torch.tensor([[2], [0]]))[0].item() == pytest.approx(p[2].log().item(), abs=1e-6)


def test_heads_are_chosen_from_the_space():
    net = torch.nn.Identity()
    assert isinstance(make_action_head(gym.spaces.Discrete(4), net), CategoricalHead)
    head = make_action_head(gym.spaces.MultiDiscrete([3, 2]), net)
    assert isinstance(head.dist({keys.LOGITS: torch.zeros(1, 5)}), MultiCategorical)
    with pytest.raises(
        UnsupportedActionSpace, match="action space Tuple.* is not supported; supported: Box, Discrete, MultiDiscrete"
    ):
        make_action_head(gym.spaces.Tuple((gym.spaces.Discrete(2),)), net)


# --- previous action, storage --------------------------------------------------------------------
def test_previous_discrete_action_is_one_hot_and_none_is_all_zeros():
    enc = InputEncoder(1, gym.spaces.Discrete(3), True, True)
    out = enc(torch.zeros(3, 1), torch.tensor([[-1], [0], [2]]), torch.tensor([[0.0], [1.0], [0.5]]))
    assert out.tolist() == [[0, 0, 0, 0, 0], [0, 1, 0, 0, 1], [0, 0, 0, 1, 0.5]]
    assert (enc.in_dim, enc.out_dim) == (3, 5)
    multi = InputEncoder(2, gym.spaces.MultiDiscrete([2, 3]), True, False)
    out = multi(torch.ones(2, 2), torch.tensor([[-1, 1], [1, -1]]))
    assert out.tolist() == [[1, 1, 0, 0, 0, 1, 0], [1, 1, 0, 1, 0, 0, 0]]


def test_action_storage_and_conversion():
    assert action_dim(gym.spaces.Discrete(4)) == 1
    assert action_dim(gym.spaces.MultiDiscrete([3, 2])) == 2
    assert action_dim(gym.spaces.Box(-1, 1, (2, 3))) == 6  # flattened, not refused
    assert to_env(torch.tensor([[2], [0]]), gym.spaces.Discrete(4, start=1)).tolist() == [3, 1]
    box = to_env(torch.arange(12.0).view(2, 6), gym.spaces.Box(-1, 1, (2, 3), np.float32))
    assert box.shape == (2, 2, 3) and box.dtype == np.float32
    with pytest.raises(UnsupportedActionSpace, match="a Box of integers"):
        check_action_space(gym.spaces.Box(0, 3, (2,), np.int64))


def test_gym_vec_env_steps_discrete_actions():
    env = GymVecEnv(lambda: make_cost_env(cost_envs.MULTI_MATCH_ID), 3)
    assert env.action_space == gym.spaces.MultiDiscrete([3, 2]) and env.action_dim == 2
    env.reset(seed=0)
    step = env.step(torch.tensor([[2, 0], [0, 1], [1, 1]]))
    assert step.cost.view(-1).tolist() == [1.0, 0.0, 0.0]  # the first component's action 2 costs 1
    env.close()
    with pytest.raises(UnsupportedActionSpace, match=r"env cost_test/Tuple-v0: action space Tuple"):
        GymVecEnv(lambda: make_cost_env(cost_envs.TUPLE_ID), 2, env_id=cost_envs.TUPLE_ID)


@pytest.mark.parametrize(
    "policy",
    [
        {"name": "mlp", "include_prev_action": True, "include_prev_cost": True},
        {"name": "transformer", "window": 4, "width": 8, "heads": 2, "feedforward": 8, "head_sizes": [8]},
    ],
)
def test_collector_stores_integer_actions_and_the_previous_one(policy):
    cfg = load_config(
        {"env": {"name": "gym", "id": cost_envs.MATCH_ID, "num_envs": 2}, "policy": policy, "rollout_steps": 20}
    )
    from cmdp_rl.envs import make_env

    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env)
    batch = Collector(env, agent, 20, seed=0).collect()
    action, prev = batch.get(keys.ACTION), batch.get(keys.PREV_ACTION)
    assert action.dtype == torch.int64 and action.shape == (2, 20, 1)
    assert ((action >= 0) & (action < 4)).all()
    init = batch.get(keys.IS_INIT).squeeze(-1)
    assert init[:, 0].all() and init[:, 8].all() and init.sum() == 2 * 3  # 8-step episodes
    assert (prev[init] == -1).all()  # no previous action at an episode's start
    assert torch.equal(prev[:, 1:][~init[:, 1:]], action[:, :-1][~init[:, 1:]])
    assert torch.equal(batch.get((keys.NEXT, keys.PREV_ACTION)), action)
    logits = batch.get(keys.LOGITS)
    lp = torch.log_softmax(logits, -1).gather(-1, action).squeeze(-1)
    assert torch.allclose(batch.get(keys.LOG_PROB), lp, atol=1e-6)
    # deterministic acting is the argmax of the logits
    out = agent.act({k: batch.get(k)[:, 3] for k in agent.in_keys}, deterministic=True)
    assert torch.equal(out[keys.ACTION], out[keys.LOGITS].argmax(-1, keepdim=True))
    env.close()


# --- CPO's Fisher-vector product on a categorical KL ---------------------------------------------
@pytest.mark.parametrize("sizes", [None, (2, 3)])
def test_fisher_vector_product_of_categorical_kl_is_softmax_fisher(sizes):
    """With the logits themselves as parameters, the Hessian of KL(old || new) at new = old is the
    softmax Fisher matrix diag(p) - p p^T (block-diagonal over independent components)."""
    head = CategoricalHead(torch.nn.Identity(), sizes)
    theta = torch.nn.Parameter(torch.tensor([0.3, -0.2, 0.5, 0.1, -0.4]))
    old = head.dist({keys.LOGITS: theta.detach().clone()})
    kl = kl_divergence(old, head.dist({keys.LOGITS: theta})).mean()
    fvp = fisher_vector_product(kl, [theta], damping=0.1)
    blocks = [5] if sizes is None else list(sizes)
    fisher = torch.zeros(5, 5)
    i = 0
    for n in blocks:
        p = torch.softmax(theta.detach()[i : i + n], -1)
        fisher[i : i + n, i : i + n] = torch.diag(p) - torch.outer(p, p)
        i += n
    v = torch.tensor([1.0, -2.0, 0.5, 3.0, -1.0])
    assert torch.allclose(fvp(v), fisher @ v + 0.1 * v, atol=1e-6)


# --- every algorithm and head; learning; checkpoints ----------------------------------------------
HEADS = {
    "mlp": {"name": "mlp", "hidden_sizes": [16], "include_prev_action": True, "include_prev_cost": True},
    "lstm": {"name": "lstm", "hidden_size": 8, "head_sizes": [8], "segment_length": 8},
    "gru": {"name": "gru", "hidden_size": 8, "head_sizes": [], "segment_length": 0},
    "transformer": {"name": "transformer", "window": 4, "width": 8, "heads": 2, "feedforward": 8, "head_sizes": [8]},
}
# The built-in algorithms (the registry's, each with its yaml) that act with the policy's own agent
# (AlgoConfig.shape_agent as it is) on any env: every head must train with each. The registry enrolment
# (tests/test_registry_enrolment.py) runs every algorithm, and any a test registers, with the MLP on Discrete and
# MultiDiscrete actions; there the off-policy ones, which reshape the agent (a squashed Gaussian actor), refuse
# categorical actions in one line.
ALGOS = [
    a
    for a in names("algo")
    if (CONFIG_DIR / "algo" / f"{a}.yaml").is_file()
    and component("algo", a).options.envs is None
    and component("algo", a).options.shape_agent is AlgoConfig.shape_agent
]
MULTI = [a for a in ALGOS if component("algo", a).options.constraints is None]  # take K > 1 costs


# A 3 x 3 grid with both hazards (tests/test_grid.py's) and short episodes: 2 iterations of 2 x 8 steps.
SMALL_GRID = {"name": "grid", "num_envs": 2, "layout": ["SaG", ".b.", "..."], "end_prob": 0.3}


def _cfg(env: str | dict, algo: str, policy: dict, steps: int, rollout: int = 16, **top) -> dict:
    """A short run of ``algo`` with the tiny options it declares (AlgoConfig.tiny)."""
    env_cfg = env if isinstance(env, dict) else {"name": "gym", "id": env, "num_envs": 2}
    return {
        "env": env_cfg,
        "algo": {"name": algo, **component("algo", algo).options.tiny},
        "policy": policy,
        "rollout_steps": rollout,
        "total_steps": steps,
        "eval_episodes": 2,
        "checkpoint_every": 100,
        **top,
    }


def _check_outputs(run, result: dict, iterations: int) -> None:
    """What a finished run writes: one metrics.csv row per iteration, every value finite (the
    reference-normalized columns stay blank: no reference), a checkpoint, eval.json with finite numbers."""
    with open(run / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["iteration"]) for r in rows] == list(range(1, iterations + 1))
    for r in rows:
        values = {k: v for k, v in r.items() if not k.startswith("normalized_")}
        assert all(v != "" and math.isfinite(float(v)) for v in values.values()), values
    assert (run / "checkpoint.pt").is_file()
    saved = json.loads((run / "eval.json").read_text())
    assert saved["episodes"] == 2 and saved["episode_return"] == result["episode_return"]
    numbers = [v for v in saved.values() if isinstance(v, (int, float)) and not isinstance(v, bool)]
    assert numbers and all(math.isfinite(v) for v in numbers)


@pytest.mark.parametrize("head", HEADS)
@pytest.mark.parametrize("algo", ALGOS)
def test_every_algorithm_and_head_on_multi_discrete_actions(tmp_path, quiet, algo, head):
    """MultiDiscrete([3, 2]), one cost: 2 iterations of 2 x 8 steps, 8-step episodes."""
    result = train(load_config(_cfg(cost_envs.MULTI_MATCH_ID, algo, HEADS[head], 32, rollout=8)), tmp_path, echo=quiet)
    _check_outputs(tmp_path, result, 2)
    assert 0 <= result["episode_return"] <= 8 and result["episode_length"] == 8


@pytest.mark.parametrize("head", HEADS)
@pytest.mark.parametrize("algo", MULTI)
def test_every_algorithm_and_head_on_discrete_actions_with_two_costs(tmp_path, quiet, algo, head):
    """Discrete(4) on env=grid, K = 2 (a budget per hazard), with every head: the algorithms that take
    several constraints (the others refuse K > 1 in one line: tests/test_registry_enrolment.py)."""
    cfg = _cfg(SMALL_GRID, algo, HEADS[head], 32, rollout=8)
    cfg["algo"]["cost_limit"] = [0.3, 0.15]
    result = train(load_config(cfg), tmp_path, echo=quiet)
    _check_outputs(tmp_path, result, 2)
    assert {"episode_cost/hazard_a", "episode_cost/hazard_b"} <= set(result)
    assert 0 <= result["episode_return"] <= 1


def test_the_algorithm_lists_are_the_registrys():
    """The lists above come from the registry's declarations: each on-policy family is in them, and only those."""
    assert {"ppo", "ppo_lag", "pid_lag", "cpo", "trpo_lag", "focops", "saute"} <= set(ALGOS)
    assert not {"sac", "sac_lag", "td3_lag", "mappo_lag"} & set(ALGOS)
    assert {"ppo", "ppo_lag", "pid_lag", "trpo_lag"} <= set(MULTI) and not {"cpo", "pcpo", "crpo"} & set(MULTI)


def test_checkpoint_reloads_and_evaluates_greedily_and_sampled(tmp_path, quiet):
    cfg = _cfg(cost_envs.MULTI_MATCH_ID, "ppo_lag", HEADS["lstm"], 64, eval_episodes=4)
    res = train(load_config(cfg), tmp_path, echo=quiet)
    trained = load_trained(tmp_path, num_envs=2)
    again = evaluate(trained.agent, trained.env, 4, deterministic=True, seed=trained.cfg.seed + 1_000_003)
    assert again["episode_return"] == res["episode_return"]  # the checkpoint is the evaluated policy
    sampled = evaluate(trained.agent, trained.env, 4, deterministic=False, seed=1)
    assert sampled["deterministic"] is False and sampled["episodes"] == 4
    trained.env.close()


@pytest.mark.parametrize(
    "env_id,random_return,min_return",
    [
        (cost_envs.MATCH_ID, 2.0, 7.5),  # a uniform policy matches 1 context in 4
        (cost_envs.MULTI_MATCH_ID, 10 / 3, 6.5),  # 8 * (1/3 + 1/2) / 2
    ],
)
@pytest.mark.slow  # a learning run (pyproject: markers)
def test_discrete_ppo_learns_the_contextual_bandit(tmp_path, quiet, env_id, random_return, min_return):
    """PPO, seed 0, 2048 steps (about 2 s): the greedy policy matches nearly every context (best: 8
    per episode) where a uniform policy earns ``random_return``."""
    cfg = {
        "env": {"name": "gym", "id": env_id, "num_envs": 4},
        "algo": {"name": "ppo", "update_epochs": 2, "num_minibatches": 2},
        "rollout_steps": 32,
        "total_steps": 2048,
        "eval_episodes": 8,
    }
    res = train(load_config(cfg), tmp_path, echo=quiet)
    assert res["episode_return"] >= min_return > random_return + 3


def test_ppo_lagrangian_avoids_the_costly_action(tmp_path, quiet):
    """Budget 0.5 per episode against the cost of 2 an unconstrained best policy pays: ppo_lag's
    greedy policy stays within it and still matches the other contexts (best feasible: 6)."""
    cfg = {
        "env": {"name": "gym", "id": cost_envs.MATCH_ID, "num_envs": 4},
        "algo": {
            "name": "ppo_lag",
            "update_epochs": 2,
            "num_minibatches": 2,
            "cost_limit": 0.5,
            "multiplier": {
                "kind": "dual",
                "lr": 0.5,
            },  # the step this check was set with (the log dual from 0.01 needs more episodes than 2048 steps give)
        },
        "rollout_steps": 32,
        "total_steps": 2048,
        "eval_episodes": 8,
    }
    res = train(load_config(cfg), tmp_path, echo=quiet)
    assert res["episode_cost"] <= 0.5 and res["episode_return"] >= 5.0


def test_unsupported_action_space_stops_train_with_one_line(tmp_path, quiet):
    with pytest.raises(ConfigError) as err:
        train(load_config({"env": {"name": "gym", "id": cost_envs.TUPLE_ID}}), tmp_path, echo=quiet)
    assert "\n" not in str(err.value) and "action space Tuple" in str(err.value)
    assert not (tmp_path / "metrics.csv").exists()


def test_train_py_on_a_discrete_gym_env(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "tests"), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run(
        [
            sys.executable,
            str(ROOT / "train.py"),
            "env=gym",
            f"env.id=helpers.cost_envs:{cost_envs.MATCH_ID}",
            "env.num_envs=2",
            "rollout_steps=16",
            "total_steps=64",
            "eval_episodes=2",
            "algo.update_epochs=1",
            "algo.num_minibatches=2",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    result = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert result["episodes"] == 2 and result["episode_length"] == 8
