"""Off-policy constrained RL (algos/off_policy.py, sac.py, td3.py): the TD targets on hand-computed
transitions, the multiplier on the cost critic, the budget conversion, the replay buffer's resume,
the refusals; learning on Reach1D with the blocking wall (lambda acts) and the passable one (goal
reached within budget)."""

import math

import pytest
import torch
from helpers.resume import assert_same_run, crash_then_resume, final_state
from helpers.runs import tiny
from tensordict import TensorDict

from cmdp_rl import keys, load_config, train
from cmdp_rl.algos import make_algo
from cmdp_rl.algos.off_policy.common import Replay, discounted_budget
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.envs import make_env
from cmdp_rl.policies import make_agent
from cmdp_rl.policies.squashed import Q_COST, Q_REWARD


def build(algo: dict, **run):
    cfg = load_config(
        {"algo": {"buffer_size": 1000, **algo}, "env": {"num_envs": 2}, "policy": {"hidden_sizes": [8]}, **run}
    )
    env = make_env(cfg.env)
    agent = make_agent(cfg.policy, env, algo=cfg.algo)
    return make_algo(cfg.algo, agent), env


def constant(net: torch.nn.Sequential, value: float) -> None:
    """Make the MLP ``net`` output ``value`` whatever its input."""
    last = net[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.fill_(value)


def transitions(reward, cost, terminated) -> TensorDict:
    n = len(reward)
    col = lambda x: torch.tensor(x, dtype=torch.float32).reshape(n, 1)  # noqa: E731
    return TensorDict(
        {
            keys.OBS: torch.rand(n, 2),
            keys.ACTION: torch.rand(n, 1) * 0.2 - 0.1,
            (keys.NEXT, keys.OBS): torch.rand(n, 2),
            (keys.NEXT, keys.REWARD): col(reward),
            (keys.NEXT, keys.COST): col(cost),
            (keys.NEXT, keys.TERMINATED): torch.tensor(terminated).reshape(n, 1),
        },
        batch_size=[n],
    )


def test_the_budget_conversion_by_hand():
    # d = 2 over T = 2 steps is 1 per step; discounted from the start: 1 + 0.5 * 1 = 1.5.
    assert discounted_budget(2.0, 0.5, 2) == pytest.approx(1.5)
    # One step: the budget itself. T = 3, gamma = 0.9: (1 + 0.9 + 0.81) d / 3.
    assert discounted_budget(4.0, 0.9, 1) == pytest.approx(4.0)
    assert discounted_budget(3.0, 0.9, 3) == pytest.approx(2.71)
    # The velocity benchmark's d = 25 over 1000 steps, gamma 0.99: 2.5 (1 - 0.99^1000) = 2.49989...
    assert discounted_budget(25.0, 0.99, 1000) == pytest.approx(2.5 * (1 - math.exp(1000 * math.log(0.99))))
    algo, env = build({"name": "sac_lag", "cost_limit": [3.0], "cost_gamma": 0.9, "episode_length": 3})
    assert algo.budgets == [pytest.approx(2.71)]
    algo, env = build({"name": "sac_lag", "cost_limit": 1.0, "cost_gamma": 0.9})  # T: Reach1D's max_steps
    assert algo.budgets == [pytest.approx((1 - 0.9**100) / (100 * 0.1))]


def test_cost_critic_target_masks_termination_and_bootstraps_truncation():
    """Target Q'_c = 2 everywhere, live Q_c = 1: y_c = c + 0.9 (1 - terminated) 2. A truncated
    step (not terminated) bootstraps from its final observation."""
    algo, _ = build({"name": "sac_lag", "cost_gamma": 0.9})
    constant(algo.targets.target[Q_COST], 2.0)
    constant(algo.agent.critics[Q_COST].net, 1.0)
    mb = transitions(reward=[0.0, 0.0], cost=[1.0, 0.5], terminated=[False, True])
    _, stats = algo.critic_loss(mb)
    y = torch.tensor([1.0 + 0.9 * 2.0, 0.5])
    assert stats["loss_qc"].item() == pytest.approx(((1.0 - y) ** 2).mean().item())  # (3.24 + 0.25) / 2


def test_reward_target_takes_the_smaller_target_twin():
    """TD3 (no entropy bonus): y = r + 0.5 (1 - terminated) min(3, 5); both live twins output 0."""
    algo, _ = build({"name": "td3", "gamma": 0.5})
    for name, value in zip(Q_REWARD, (3.0, 5.0)):
        constant(algo.targets.target[name], value)
        constant(algo.agent.critics[name].net, 0.0)
    mb = transitions(reward=[1.0, 2.0], cost=[0.0, 0.0], terminated=[False, True])
    _, stats = algo.critic_loss(mb)
    y = torch.tensor([1.0 + 0.5 * 3.0, 2.0])
    assert stats["loss_q"].item() == pytest.approx(2 * (y**2).mean().item())  # the sum of both twins' MSE


@pytest.mark.parametrize("name", ["sac_lag", "td3_lag"])
def test_the_multiplier_rises_above_the_budget_and_falls_below(name):
    """The cost critic held at a constant Q_c (learning rate ~0): one update moves lambda by
    multiplier.lr * (Q_c - d_Q), d_Q the discounted budget: up at Q_c = 5, down at Q_c = 0."""
    algo, env = build(
        {
            "name": name,
            "warmup_steps": 0,
            "batch_size": 4,
            "critic_lr": 1e-12,
            # the step in the cost's own units, as the docstring computes it
            "multiplier": {"scale": "none", "lr": 0.1, "init": 0.3},
            "policy_delay": 1,
        }
        if name == "td3_lag"
        else {
            "name": name,
            "warmup_steps": 0,
            "batch_size": 4,
            "critic_lr": 1e-12,
            "multiplier": {"scale": "none", "lr": 0.1, "init": 0.3},
        },
        rollout_steps=2,
    )
    d_q = algo.budgets[0]
    from cmdp_rl.rollout.collector import Collector

    collector = Collector(env, algo.agent, 2, seed=0)
    constant(algo.agent.critics[Q_COST].net, 5.0)
    stats = algo.update(collector.collect())
    assert stats["gradient_steps"] == 4 and stats["q_cost"] == pytest.approx(5.0, abs=1e-4)
    assert stats["lagrange_multiplier"] == pytest.approx(0.3 + 0.1 * (5.0 - d_q), abs=1e-4)
    constant(algo.agent.critics[Q_COST].net, 0.0)
    before = stats["lagrange_multiplier"]
    stats = algo.update(collector.collect())
    assert stats["lagrange_multiplier"] == pytest.approx(before - 0.1 * d_q, abs=1e-4)
    env.close()


class FirstFeature(torch.nn.Module):
    """A cost critic that reads the state's first feature (Reach1D's position), whatever the action."""

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return h[..., :1]


def positions(x: float, n: int) -> TensorDict:
    batch = transitions(reward=[0.0] * n, cost=[0.0] * n, terminated=[False] * n)
    batch.get(keys.OBS)[:, 0] = x
    return batch


def test_replay_newest_reads_the_last_rows_across_the_wrap():
    replay = Replay(10, 4, "memory")
    replay.add(positions(0.0, 7))
    assert replay.newest(3).get(keys.OBS)[:, 0].tolist() == [0.0] * 3
    replay.add(positions(1.0, 5))  # rows 7, 8, 9, then 0, 1: the newest five wrap around the end
    assert replay.newest(6).get(keys.OBS)[:, 0].tolist() == [0.0] + [1.0] * 5
    assert len(replay.newest(50)) == 10


@pytest.mark.parametrize("name", ["sac_lag", "td3_lag"])
def test_the_multiplier_reads_q_c_on_the_newest_states(name):
    """Q_c(s, a) = position: 900 old transitions at 0, then 100 new at 1. The multiplier's estimate
    averages over the newest cost_window states (1.0 at a window of 100; 0.5 at 200), not over a
    uniform replay sample, which would read about 0.1; cost_window=0 reads the replayed states."""
    for window, expected in ((100, 1.0), (200, 0.5)):
        algo, _ = build({"name": name, "cost_window": window})
        algo.agent.critics[Q_COST].net = FirstFeature()
        algo.replay.add(positions(0.0, 900))
        algo.replay.add(positions(1.0, 100))
        assert algo.cost_estimate().tolist() == pytest.approx([expected])
    algo, env = build(
        {
            "name": name,
            "cost_window": 0,
            "warmup_steps": 0,
            "batch_size": 64,
            "multiplier": {"lr": 1.0},
            "policy_delay": 1,
        }
        if name == "td3_lag"
        else {"name": name, "cost_window": 0, "warmup_steps": 0, "batch_size": 64, "multiplier": {"lr": 1.0}}
    )
    algo.agent.critics[Q_COST].net = FirstFeature()
    algo.replay.add(positions(0.0, 900))
    stats = algo.update(positions(1.0, 100))  # 100 gradient steps on replayed states
    assert 0.05 < stats["q_cost"] < 0.15


def test_warm_up_acts_uniformly_and_does_not_update():
    algo, env = build({"name": "sac", "warmup_steps": 8, "batch_size": 4})
    from cmdp_rl.rollout.collector import Collector

    collector = Collector(env, algo.agent, 2, seed=0, uniform_steps=8)
    first = collector.collect()  # 4 steps of 2 envs: all uniform (log-density of U(-0.1, 0.1) = log 5)
    assert torch.allclose(first.get(keys.LOG_PROB), torch.full((2, 2), math.log(5.0)))
    assert algo.update(first)["gradient_steps"] == 0  # 4 stored of the 8 warm-up transitions
    assert algo.update(collector.collect())["gradient_steps"] == 4  # 8 stored: utd_ratio 1 x 4 new
    third = collector.collect()  # the policy acts: a tanh-Gaussian's log-density, not the uniform's
    assert not torch.allclose(third.get(keys.LOG_PROB), torch.full((2, 2), math.log(5.0)))
    env.close()


@pytest.mark.parametrize("storage", ["memory", "memmap"])
def test_replay_state_restores_the_buffer_exactly(storage):
    """Past its capacity (the writer wrapped round): same rows, same cursor, same samples; the state
    of a memory-mapped buffer loads into either kind."""
    a = Replay(6, 3, storage)
    for i in range(3):  # 9 transitions in a buffer of 6
        a.add(transitions([float(3 * i + j) for j in range(3)], [0.0] * 3, [False] * 3).unsqueeze(0))
    b = Replay(6, 3, "memory")
    b.load_state_dict(a.state_dict())
    assert len(b) == 6
    assert torch.equal(
        a.buffer.storage.get(torch.arange(6)).get((keys.NEXT, keys.REWARD)).flatten(),
        torch.tensor([6.0, 7.0, 8.0, 3.0, 4.0, 5.0]),
    )
    for rb in (a, b):
        rb.add(transitions([9.0], [0.0], [False]).unsqueeze(0))  # overwrites row 3
    torch.manual_seed(1)
    sa = a.sample()
    torch.manual_seed(1)
    sb = b.sample()
    assert (sa == sb).all()


def test_sac_lag_resumes_exactly_with_its_buffer(tmp_path, monkeypatch, quiet):
    cfg = tiny(algo={"name": "sac_lag", "warmup_steps": 32, "batch_size": 16, "buffer_size": 64, "utd_ratio": 0.5})
    for k in ("update_epochs", "num_minibatches"):
        cfg["algo"].pop(k)
    cfg["policy"] = {"hidden_sizes": [16]}
    whole, broken = crash_then_resume(cfg, tmp_path, monkeypatch, quiet)
    assert_same_run(whole, broken)
    replay = final_state(broken)["replay"]
    assert replay["len"] == 64 and torch.equal(
        replay["data"]["observation"], final_state(whole)["replay"]["data"]["observation"]
    )


@pytest.mark.parametrize(
    "override, message",
    [
        ({"policy": {"name": "lstm"}}, "policy must be mlp for algo=sac_lag"),
        ({"algo": {"name": "sac"}, "env": {"name": "grid"}}, "sac needs a Box action space"),
        (
            {"algo": {"name": "sac_lag", "episode_length": 10}, "env": {"name": "grid"}},
            "sac_lag needs a Box action space",
        ),
        (
            {"algo": {"name": "sac_lag", "buffer_size": 8, "batch_size": 16}},
            "algo.buffer_size must be >= algo.batch_size",
        ),
        ({"algo": {"name": "sac_lag", "utd_ratio": 0}}, "algo.utd_ratio must be in (0, 64]"),
        (
            {"algo": {"name": "td3_lag", "multiplier": {"kind": "adam"}}},
            "algo.multiplier.kind must be one of ('dual', 'pid', 'regularized', 'optimistic', 'augmented')",
        ),
    ],
)
def test_refusals_are_one_line(tmp_path, quiet, override, message):
    cfg = {"algo": {"name": "sac_lag"}, **override}
    with pytest.raises(ConfigError) as exc:
        train(load_config(cfg), tmp_path / "run", echo=quiet)
    assert message in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / "run").exists()


# Reach1D with the blocking wall, 30-step episodes: every push into the wall costs 1 and gains
# nothing, so only the multiplier keeps the policy off it. Short horizon (gamma 0.9) so that the
# Q-critics' TD targets settle in a few thousand steps.
REACH = {
    "env": {"max_steps": 30},
    "algo": {
        "name": "sac_lag",
        "cost_limit": 1.0,
        "gamma": 0.9,
        "cost_gamma": 0.9,
        "warmup_steps": 300,
        "utd_ratio": 0.5,
        "batch_size": 64,
        "lr": 1e-3,
        "critic_lr": 1e-3,
        "alpha_init": 0.1,
        "alpha_lr": 1e-3,
        "multiplier": {"lr": 0.05},
    },
    "policy": {"hidden_sizes": [32, 32], "activation": "relu"},
    "seed": 0,
    "total_steps": 3000,
    "eval_episodes": 8,
    "checkpoint_every": 1000,
}


@pytest.mark.slow  # a learning run (pyproject: markers)
def test_sac_lag_learns_reach1d_within_budget(tmp_path, quiet):
    """3,000 steps (about 30 s): the eval policy (tanh of the mean, through the usual evaluation)
    stays within budget d = 1 and gets most of the DP optimum's return (0.399: the wall caps it);
    lambda had to act."""
    cfg = load_config(REACH)
    result = train(cfg, tmp_path, echo=quiet)
    assert result["episode_cost"] <= 1.0, result
    assert result["episode_return"] >= 0.6 * cfg.env.optimum(1.0), result
    from helpers.runs import metrics_rows

    assert max(float(r["lagrange_multiplier"]) for r in metrics_rows(tmp_path)) > 0.05


# Reach1D with the passable wall (env.wall=pass): the goal is reached only by crossing, and each
# crossing costs 1. At d = 1 the exact optimum (reach1d_dp.py) crosses once and reaches the goal:
# return 1.8 (0.8 of shaped progress + 1 at the goal). 15-step episodes (the goal takes 8 full-speed
# moves), so the budget conversion's T (max_steps) is near the real episode length. The budget does
# not bind at the optimum (its multiplier is 0): this checks that the Lagrangian does not
# over-correct (stop at the wall); the blocking-wall test above checks that lambda acts.
REACH_PASS = {**REACH, "env": {"wall": "pass", "max_steps": 15}, "total_steps": 6000, "checkpoint_every": 100000}
TD3_OPTIONS = ("alpha_init", "alpha_lr")  # SAC's entropy options: td3_lag refuses them


@pytest.mark.slow  # a learning run (pyproject: markers)
@pytest.mark.parametrize("name", ["sac_lag", "td3_lag"])
def test_off_policy_lag_reaches_the_goal_through_the_wall_within_budget(tmp_path, quiet, name):
    """6,000 steps (sac_lag 9.5 s, td3_lag 7 s at load 3): the eval policy reaches the goal in
    most episodes, at cost within d = 1, with a return near the optimum's 1.8. A policy that never
    crosses gets at most 0.4 (up to the wall) and no goal; one that crosses back and forth pays 2 or
    more. At 4,000 steps sac_lag reached the goal in every eval episode in only 4 of seeds 0-8 (in
    3 it crossed and stopped short: return 0.70); at 6,000 it did in each of seeds 0-5, td3_lag in
    each of 0-2."""
    algo = {k: v for k, v in REACH["algo"].items() if name == "sac_lag" or k not in TD3_OPTIONS}
    cfg = load_config({**REACH_PASS, "algo": {**algo, "name": name}})
    from cmdp_rl.envs.reach1d.optimum import constrained_optimum

    best = constrained_optimum(cfg.env, 1.0)
    assert best.cost == 1.0 and best.value == pytest.approx(1.8)  # one crossing, goal reached
    result = train(cfg, tmp_path, echo=quiet)
    assert result["episode_cost"] <= 1.0, result
    assert result["goal_reached"] >= 0.75, result
    assert result["episode_return"] >= 0.8 * best.value, result


def test_one_multiplier_per_constraint_on_the_cost_critics_k_outputs(tmp_path, quiet):
    """K = 2 (tests/helpers/cost_envs.py's TwoCost: the first cost is paid for every rewarding action, the
    second never): one λ column per cost; the first rises, the second (estimate 0 < budget) stays 0."""
    from helpers.cost_envs import two_cost_cfg
    from helpers.runs import metrics_rows

    # A short discount (d_Q = 0.5 (1 - 0.5^4) / (4 x 0.5) = 0.23 for the first cost) and a fast critic:
    # Q_c of the first cost passes its budget within the run's 80 gradient steps.
    cfg = two_cost_cfg(
        algo={
            "name": "sac_lag",
            "episode_length": 4,
            "warmup_steps": 32,
            "batch_size": 16,
            "multiplier": {"lr": 0.5},
            "utd_ratio": 0.5,
            "gamma": 0.5,
            "cost_gamma": 0.5,
            "critic_lr": 1e-2,
        }
    )
    cfg["algo"].pop("update_epochs"), cfg["algo"].pop("num_minibatches")
    cfg["policy"] = {"hidden_sizes": [16]}
    train(load_config(cfg), tmp_path, echo=quiet)
    last = metrics_rows(tmp_path)[-1]
    assert float(last["lagrange_multiplier/hazard_a"]) > 0.0
    assert float(last["lagrange_multiplier/hazard_b"]) == 0.0


def test_the_pid_multiplier_acts_on_the_cost_critic():
    """algo.multiplier.kind=pid: lambda = kp (Q_c - d_Q) + I, I += ki (Q_c - d_Q) (multiplier.PIDLagrangian)."""
    algo, env = build(
        {
            "name": "sac_lag",
            "warmup_steps": 0,
            "batch_size": 4,
            "critic_lr": 1e-12,
            "multiplier": {"kind": "pid", "scale": "none", "kp": 1.0, "ki": 0.1, "init": 0.3},
        },
        rollout_steps=2,
    )
    from cmdp_rl.rollout.collector import Collector

    collector = Collector(env, algo.agent, 2, seed=0)
    d_q = algo.budgets[0]
    constant(algo.agent.critics[Q_COST].net, 5.0)
    integral = 0.3 + 0.1 * (5.0 - d_q)
    assert algo.update(collector.collect())["lagrange_multiplier"] == pytest.approx(
        1.0 * (5.0 - d_q) + integral, abs=1e-4
    )
    constant(algo.agent.critics[Q_COST].net, 0.0)
    integral -= 0.1 * d_q
    assert algo.update(collector.collect())["lagrange_multiplier"] == pytest.approx(max(0.0, integral - d_q), abs=1e-4)
    env.close()


def test_sacs_written_out_log_prob_is_the_tanh_normals():
    """SAC.sample's log pi (written out for speed) is the head's torchrl TanhNormal density in the
    squashed units, where the latter's inverse tanh is accurate (|a| < 0.9); finite everywhere."""
    torch.manual_seed(0)
    algo, env = build({"name": "sac_lag"})
    head = algo.agent.actor.head
    with torch.no_grad():
        head.net[-1].weight.normal_(0.0, 1.0)
        head.net[-1].bias.normal_(0.0, 1.0)
        x = torch.randn(2000, 2) * 3
        a, log_pi = algo.sample(x)
        ref = (
            head.dist(head(x)).log_prob(head.low + head.half_width * (a + 1)).unsqueeze(-1)
            + head.half_width.log().sum()
        )
    inside = a.abs().squeeze(-1) < 0.9
    assert inside.sum() > 200 and (~inside).sum() > 200  # both regimes sampled
    assert torch.allclose(log_pi[inside], ref[inside], atol=1e-3)
    assert torch.isfinite(log_pi).all()
    env.close()
