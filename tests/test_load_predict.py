"""``cmdp_rl.load(run_dir).predict(obs)``: the policy a run deployed, acting as SB3's ``predict`` does, with
the state it carries between calls. Its actions are the collector's own, step for step, on the same env."""

import numpy as np
import pytest
import torch
from helpers.runs import tiny

import cmdp_rl
from cmdp_rl import load_config, train
from cmdp_rl.envs import make_eval_env
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.run.rundir import load_trained

CASES = {
    "mlp_mixture": tiny(),  # ppo_lag on Reach1D: deploy.policy=auto deploys a valued mixture
    "lstm_prev_cost": tiny(
        deploy={"policy": "last"},
        policy={"name": "lstm", "hidden_size": 8, "head_sizes": [8], "segment_length": 8, "include_prev_cost": True},
    ),
    "discrete_fork": {**tiny(deploy={"policy": "average"}), "env": {"name": "fork", "num_envs": 2}},
}


def rollout_with_predict(policy, env, steps: int, seed: int) -> list[np.ndarray]:
    obs, state, start, cost, actions = env.reset(seed=seed), None, None, None, []
    for _ in range(steps):
        needs = policy.needs_cost and state is not None
        action, state = policy.predict(obs.numpy(), state, episode_start=start, cost=cost if needs else None)
        actions.append(np.asarray(action))
        step = env.step(torch.as_tensor(action).reshape(env.num_envs, -1))  # the collector's [N, action_dim]
        obs, start, cost = step.obs, (step.terminated | step.truncated).numpy(), step.cost.numpy()
    return actions


@pytest.mark.parametrize("case", CASES)
def test_predict_acts_as_the_collector_does_on_the_deployed_policy(case, tmp_path):
    train(load_config(CASES[case]), tmp_path)
    policy = cmdp_rl.load(tmp_path)
    trained = load_trained(tmp_path, num_envs=2)
    steps = 30
    torch.manual_seed(5)
    expected = Collector(trained.env, trained.agent, steps, seed=3, deterministic=True).collect()
    env = make_eval_env(trained.cfg.env, num_envs=2, algo=trained.cfg.algo)
    torch.manual_seed(5)
    got = rollout_with_predict(policy, env, steps, seed=3)
    want = expected.get(keys.ACTION).numpy()  # [N, T, ...]
    for t, action in enumerate(got):
        np.testing.assert_array_equal(action.reshape(want[:, t].shape), want[:, t])


def test_predict_takes_one_observation_and_refuses_a_missing_cost(tmp_path):
    train(load_config(CASES["lstm_prev_cost"]), tmp_path)
    policy = cmdp_rl.load(tmp_path)
    action, state = policy.predict(np.array([0.1, 0.9], dtype=np.float32))
    assert action.shape == (1,) and np.isfinite(action).all()
    with pytest.raises(ValueError, match="cost="):
        policy.predict(np.array([0.1, 0.9], dtype=np.float32), state)
    action, _ = policy.predict(np.array([0.1, 0.9], dtype=np.float32), state, cost=[0.0])
    assert action.shape == (1,)
