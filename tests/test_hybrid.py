"""Hybrid (hierarchical) action spaces: a skill and its continuous parameters.

The distribution's log-probability, entropy and KL against hand-computed values, its Fisher matrix
(the Hessian CPO's and TRPO's Fisher-vector product takes) against the closed form, sampling
conditioned on the skill, greedy actions; the action plumbing of Tuple and Dict spaces; env=skills
and its skill hold; every on-policy algorithm trains on it; ppo_lag reaches the goal within the
budget; resume is exact."""

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers.runs import eval_result, metrics_rows

from cmdp_rl import load_config, train
from cmdp_rl.algos.trust_region.natural_gradient import fisher_vector_product
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.envs import GymVecEnv, check_env, make_env
from cmdp_rl.envs.hold import HeldSkill
from cmdp_rl.policies.agent import make_agent
from cmdp_rl.policies.distributions import make_action_head
from cmdp_rl.policies.hybrid import HybridHead, SkillParameters
from cmdp_rl.rollout.actions import (
    UnsupportedActionSpace,
    action_bounds,
    action_dim,
    check_action_space,
    hybrid,
    to_env,
)
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.run.checkpoint import load_checkpoint

LOG_2PI = math.log(2 * math.pi)


def p_and_q() -> tuple[SkillParameters, SkillParameters]:
    """p: skills 1/4, 3/4, N(0.5, 1) and N(-1, 2); q: skills 1/2, 1/2, N(0, 1) and N(-1, 1)."""
    p = SkillParameters(torch.tensor([0.0, math.log(3)]), torch.tensor([[0.5], [-1.0]]), torch.tensor([[1.0], [2.0]]))
    q = SkillParameters(torch.tensor([0.0, 0.0]), torch.tensor([[0.0], [-1.0]]), torch.tensor([[1.0], [1.0]]))
    return p, q


def test_log_prob_entropy_and_kl_by_hand():
    p, q = p_and_q()
    # skill 1, x = 0: log 3/4 + log N(0; -1, 2)
    want = math.log(0.75) - 0.5 * LOG_2PI - math.log(2.0) - 1.0 / 8
    assert p.log_prob(torch.tensor([1.0, 0.0])).item() == pytest.approx(want, abs=1e-6)
    assert p.log_prob(torch.tensor([0.0, 0.5])).item() == pytest.approx(math.log(0.25) - 0.5 * LOG_2PI, abs=1e-6)
    # H = H(skill) + sum_k p_k H(N_k), H(N(s)) = 1/2 log(2 pi e s^2)
    h_skill = -(0.25 * math.log(0.25) + 0.75 * math.log(0.75))
    h = h_skill + 0.25 * 0.5 * (LOG_2PI + 1) + 0.75 * 0.5 * (LOG_2PI + 1 + math.log(4.0))
    assert p.entropy().item() == pytest.approx(h, abs=1e-6)
    # KL = KL(skill) + sum_k p_k KL(N_k || N'_k), KL(N(m1,s1)||N(m2,s2)) = log s2/s1 + (s1^2 + dm^2)/(2 s2^2) - 1/2
    kl_skill = 0.25 * math.log(0.5) + 0.75 * math.log(1.5)
    kl = kl_skill + 0.25 * (0 + 1.25 / 2 - 0.5) + 0.75 * (math.log(0.5) + 4 / 2 - 0.5)
    assert torch.distributions.kl_divergence(p, q).item() == pytest.approx(kl, abs=1e-6)
    assert torch.distributions.kl_divergence(p, p).item() == pytest.approx(0.0, abs=1e-7)


def test_samples_follow_the_chosen_skills_gaussian_and_agree_with_the_kl():
    p, q = p_and_q()
    torch.manual_seed(0)
    batch = SkillParameters(*(t.expand(200_000, *t.shape) for t in (p.skill.logits, p.loc, p.scale)))
    x = batch.sample()
    k = x[:, 0].long()
    assert set(x[:, 0].tolist()) == {0.0, 1.0} and k.float().mean().item() == pytest.approx(0.75, abs=0.01)
    for skill, (mean, std) in enumerate(((0.5, 1.0), (-1.0, 2.0))):
        xs = x[k == skill, 1]
        assert xs.mean().item() == pytest.approx(mean, abs=0.02) and xs.std().item() == pytest.approx(std, abs=0.02)
    monte_carlo = (batch.log_prob(x) - SkillParameters(q.skill.logits, q.loc, q.scale).log_prob(x)).mean()
    assert monte_carlo.item() == pytest.approx(torch.distributions.kl_divergence(p, q).item(), abs=0.01)


def test_greedy_action_is_the_likeliest_skill_and_its_mean():
    p, _ = p_and_q()
    assert p.deterministic_sample.tolist() == [1.0, -1.0]


def test_fisher_vector_product_is_the_exact_fisher_matrix():
    """The Hessian of KL(p_old || p_theta) at theta = old, which fisher_vector_product multiplies
    by, against the closed form: for the logits diag(pi) - pi pi^T, for skill k's mean pi_k / s_k^2,
    for its log-std 2 pi_k (the Gaussian blocks weighted by the skill's probability)."""
    logits = torch.tensor([0.3, -0.2, 0.5])
    loc = torch.tensor([[0.1], [-0.4], [0.7]])
    log_std = torch.tensor([[0.0], [-0.5], [0.4]])
    theta = torch.nn.Parameter(torch.cat([logits, loc.reshape(-1), log_std.reshape(-1)]))

    def dist(t: torch.Tensor) -> SkillParameters:
        return SkillParameters(t[:3], t[3:6].reshape(3, 1), t[6:9].reshape(3, 1).exp())

    old = dist(theta.detach())
    kl = torch.distributions.kl_divergence(old, dist(theta))
    fvp = fisher_vector_product(kl, [theta], damping=0.0)
    hessian = torch.stack([fvp(e) for e in torch.eye(9)])
    pi = logits.softmax(-1)
    want = torch.zeros(9, 9)
    want[:3, :3] = torch.diag(pi) - torch.outer(pi, pi)
    want[3:6, 3:6] = torch.diag(pi / log_std.reshape(-1).exp() ** 2)
    want[6:9, 6:9] = torch.diag(2 * pi)
    torch.testing.assert_close(hessian, want, atol=1e-5, rtol=1e-5)


def test_tuple_and_dict_spaces_store_and_send_actions():
    box = gym.spaces.Box(-2.0, 2.0, shape=(2,), dtype=np.float32)
    t = gym.spaces.Tuple((gym.spaces.Discrete(3, start=1), box))
    d = gym.spaces.Dict({"params": box, "skill": gym.spaces.Discrete(3)})
    for space in (t, d):
        check_action_space(space)
        assert action_dim(space) == 3
        low, high = action_bounds(space)
        assert low.tolist() == [0, -2, -2] and high.tolist() == [2, 2, 2]
    stored = torch.tensor([[2.0, 0.5, -0.5], [0.0, 1.0, 1.5]])
    skill, params = to_env(stored, t)
    assert skill.tolist() == [3, 1] and params.shape == (2, 2)  # start added
    sent = to_env(stored, d)
    assert sent["skill"].tolist() == [2, 0] and sent["params"].tolist() == [[0.5, -0.5], [1.0, 1.5]]
    assert hybrid(d).skill_at == "skill"
    for bad in (
        gym.spaces.Tuple((gym.spaces.Discrete(2), gym.spaces.Discrete(2))),
        gym.spaces.Tuple((gym.spaces.Discrete(2), box, box)),
        gym.spaces.Dict({"a": gym.spaces.Discrete(2), "b": gym.spaces.Box(0, 3, (1,), dtype=np.int64)}),
    ):
        with pytest.raises(UnsupportedActionSpace, match="is not supported; supported: Box, Discrete"):
            check_action_space(bad)
    head = make_action_head(t, torch.nn.Linear(4, HybridHead.outputs(hybrid(t))))
    params = head(torch.zeros(5, 4))
    assert params["logits"].shape == (5, 3) and params["loc"].shape == (5, 3, 2)


class DictSkills(gym.Env):
    """A gymnasium env with a Dict hybrid action: the skill's parameter, signed by the skill, is the reward."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
    action_space = gym.spaces.Dict(
        {"skill": gym.spaces.Discrete(2), "params": gym.spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)}
    )

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, dtype=np.float32), {}

    def step(self, action):
        self.t += 1
        skill, a = int(action["skill"]), float(np.clip(action["params"][0], -1, 1))
        reward = a if skill == 0 else -a
        return np.zeros(1, dtype=np.float32), reward, False, self.t >= 5, {"cost": float(skill)}


def test_a_gymnasium_env_with_a_dict_hybrid_space_passes_the_contract_and_collects():
    assert check_env(DictSkills(), steps=20).num_costs == 1
    env = GymVecEnv(DictSkills, 3)
    assert env.action_dim == 2 and env.action_high.tolist() == [1.0, 1.0]
    cfg = load_config({"env": {"name": "skills"}})
    agent = make_agent(cfg.policy, env)
    batch = Collector(env, agent, rollout_steps=6, seed=0).collect()
    action = batch.get("action")
    assert action.shape == (3, 6, 2) and set(action[..., 0].unique().tolist()) <= {0.0, 1.0}
    assert torch.equal(batch.get(("next", "cost")).squeeze(-1), action[..., 0])  # the env saw the skill
    expect = torch.where(action[..., 0] == 0, action[..., 1], -action[..., 1]).clamp(-1, 1)
    torch.testing.assert_close(batch.get(("next", "reward")).squeeze(-1), expect)


def test_skills_env_by_hand_and_the_contract():
    cfg = load_config({"env": {"name": "skills"}}).env
    env = make_env(cfg, num_envs=2)
    check_env(make_env(cfg, num_envs=2), steps=50)
    env.reset(seed=0)
    # env 0 dashes (parameter -1: forward, the dash's parameter points back), env 1 walks forward
    s = env.step(torch.tensor([[1.0, -1.0], [0.0, 1.0]]))
    torch.testing.assert_close(s.next_obs, torch.tensor([[0.35, 0.05], [0.1, 0.05]]))
    torch.testing.assert_close(s.reward.squeeze(-1), torch.tensor([0.25, 0.0]))
    assert s.cost.squeeze(-1).tolist() == [1.0, 0.0]
    total, done = 0.0, False
    env.reset()
    for _ in range(10):  # walking only: 10 steps, return 1.0, the goal reached on the last
        s = env.step(torch.tensor([[0.0, 1.0], [0.0, 1.0]]))
        total += s.reward[0].item()
        done = bool(s.terminated[0])
    assert done and total == pytest.approx(1.0, abs=1e-5)
    with pytest.raises(ConfigError, match="env.hold"):
        load_config({"env": {"name": "skills", "hold": 0}})


def test_held_skill_ignores_the_policy_between_decisions_and_saves_its_state():
    cfg = load_config({"env": {"name": "skills", "hold": 3}}).env
    env = make_env(cfg, num_envs=1)
    assert isinstance(env, HeldSkill) and env.obs_dim == 2 + 2 + 1
    obs = env.reset()
    assert obs[0, 2:].tolist() == [0, 0, 0]  # no skill held yet, a decision step
    costs = []
    for skill in (1, 0, 0, 0, 1, 1):  # decisions at steps 1 and 4: dash held for 3 steps, then walk
        s = env.step(torch.tensor([[float(skill), -1.0]]))
        costs.append(s.cost.item())
        if len(costs) == 2:
            assert s.obs[0, 2:].tolist() == pytest.approx([0, 1, 2 / 3])
            saved = env.state_dict()
    assert costs == [1, 1, 1, 0, 0, 0]
    env.load_state_dict(saved)
    assert env.step(torch.tensor([[0.0, 0.0]])).cost.item() == 1.0  # the dash is still held


ON_POLICY = ["ppo", "penalty", "ppo_lag", "pid_lag", "cpo", "trpo_lag", "pcpo", "crpo", "focops", "cup", "saute"]


@pytest.mark.parametrize("algo", ON_POLICY)
def test_every_on_policy_algorithm_trains_on_a_hybrid_space(tmp_path, quiet, algo):
    cfg = {"env": {"name": "skills", "num_envs": 4, "hold": 2}, "algo": {"name": algo}}
    cfg.update(rollout_steps=16, total_steps=2 * 64, eval_episodes=2, log_interval=1)
    result = train(load_config(cfg), tmp_path, echo=quiet)
    assert len(metrics_rows(tmp_path)) == 2 and math.isfinite(result["episode_return"])


HYBRID_PPO_LAG = {
    "env": {"name": "skills"},
    "algo": {"name": "ppo_lag", "cost_limit": 1.0},
    "total_steps": 40 * 1024,
    "rollout_steps": 64,
    "eval_episodes": 20,
}


def test_ppo_lag_reaches_the_goal_within_budget(tmp_path, quiet):
    """Seeded; the untrained policy dashes half the time (about 9 dashes an episode) and rarely
    arrives. Trained, every greedy episode reaches the goal within the budget of 1 dash."""
    result = train(load_config(HYBRID_PPO_LAG), tmp_path, echo=quiet)
    assert result["goal_reached"] >= 0.9
    assert result["episode_cost"] <= HYBRID_PPO_LAG["algo"]["cost_limit"]
    assert result["episode_return"] >= 0.95  # walking all the way is 1.0


def test_resume_is_exact(tmp_path, quiet):
    cfg = {
        "env": {"name": "skills", "num_envs": 4, "hold": 2},
        "algo": {"name": "ppo_lag", "update_epochs": 2, "num_minibatches": 2},
        "rollout_steps": 16,
        "total_steps": 6 * 64,
        "checkpoint_every": 2,
        "eval_episodes": 4,
    }
    long, short = tmp_path / "long", tmp_path / "short"
    train(load_config(cfg), long, echo=quiet)
    train(load_config({**cfg, "total_steps": 3 * 64}), short, echo=quiet)
    train(load_config({**cfg, "resume": str(short)}), echo=quiet)
    assert metrics_rows(long) == metrics_rows(short) and eval_result(long) == eval_result(short)
    a, b = (load_checkpoint(d / "checkpoint.pt")["members"][0]["algo_state"]["networks"] for d in (long, short))
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("algo", ["sac_lag", "td3"])
def test_off_policy_algorithms_refuse_a_hybrid_space_in_one_line(tmp_path, quiet, algo):
    with pytest.raises(ConfigError, match=f"on-policy algorithm .* for a discrete or hybrid action space: {algo}"):
        train(load_config({"env": {"name": "skills"}, "algo": {"name": algo}, "total_steps": 64}), tmp_path, echo=quiet)
