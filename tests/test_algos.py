"""One update of each algorithm on a real batch; how each forms its policy advantage; NaN stop."""

import copy
import csv

import pytest
import torch

from cmdp_rl import Collector, TrainingDiverged, keys, load_config, make_agent, make_algo, make_env, train
from cmdp_rl.algos.ppo import PPO
from cmdp_rl.config.validation import ConfigError
from cmdp_rl.run.checkpoint import CheckpointError, load_checkpoint
from cmdp_rl.run.migrations import saved_config_nodes


def setup(algo: dict, **env):
    if algo.get("name") == "ppo_lag":  # the dual ascent on raw advantages these checks compute by hand (pinned, as
        algo = {"advantage_scale": "raw", **algo}  # helpers.runs' TINY pins it; the defaults: test_advantage_scale)
        if "multiplier" in algo:
            algo["multiplier"] = {"kind": "dual", **algo["multiplier"]}
    cfg = load_config({"algo": algo, "env": {"num_envs": 2, "max_steps": 20, **env}, "rollout_steps": 32})
    torch.manual_seed(0)
    e = make_env(cfg.env)
    ac = make_agent(cfg.policy, e)
    return cfg, make_algo(cfg.algo, ac), Collector(e, ac, cfg.rollout_steps, seed=0)


@pytest.mark.parametrize("name", ["ppo", "penalty", "ppo_lag", "pid_lag"])
def test_one_update_changes_every_network(name):
    cfg, algo, col = setup({"name": name, "update_epochs": 2, "num_minibatches": 2})
    before = [p.detach().clone() for p in algo.agent.parameters()]
    stats = algo.update(col.collect())
    after = list(algo.agent.parameters())
    assert all(not torch.equal(b, a) for b, a in zip(before, after))
    assert all(v == v for v in stats.values())  # finite, not NaN
    assert {"loss_pi", "loss_v", "loss_vc", "kl", "entropy", "lagrange_multiplier"} <= stats.keys()


def test_policy_advantages():
    adv = torch.tensor([[[1.0], [2.0]]])
    cadv = torch.tensor([[[0.5], [-1.0]]])
    from tensordict import TensorDict

    b = TensorDict({keys.ADVANTAGE: adv, keys.COST_ADVANTAGE: cadv}, [1, 2])
    _, ppo, _ = setup({"name": "ppo"})
    _, pen, _ = setup({"name": "penalty", "penalty": 2.0})
    _, lag, _ = setup({"name": "ppo_lag", "multiplier": {"init": 3.0}})
    assert torch.equal(ppo.policy_advantage(b), adv) and ppo.lagrange_multiplier == 0.0
    assert torch.allclose(pen.policy_advantage(b), adv - 2.0 * cadv) and pen.lagrange_multiplier == 2.0
    assert torch.allclose(lag.policy_advantage(b), (adv - 3.0 * cadv) / 4.0)


def test_lagrangian_update_moves_lambda_with_the_batch_cost():
    # wall=pass with 3-step episodes from 0.45: almost every episode crosses (cost 1 > d = 0.2)
    _, lag, col = setup(
        {"name": "ppo_lag", "cost_limit": 0.2, "multiplier": {"lr": 0.5}, "update_epochs": 1},
        wall="pass",
        start=0.45,
        max_steps=3,
    )
    stats = lag.update(col.collect())
    assert stats["lagrange_multiplier"] > 0.0
    _, lag, col = setup(
        {"name": "ppo_lag", "cost_limit": 5.0, "multiplier": {"init": 1.0, "lr": 0.5}, "update_epochs": 1}
    )
    assert lag.update(col.collect())["lagrange_multiplier"] < 1.0  # cost 0 < d: lambda falls


def test_pid_lagrangian_algorithm_uses_its_controller_and_checkpoints_it():
    # Same over-budget batches as above: with Kp > 0 lambda jumps by Kp * (J_c - d) at once.
    env = dict(wall="pass", start=0.45, max_steps=3)
    algo_cfg = {"cost_limit": 0.2, "update_epochs": 1}
    _, lag, col = setup({"name": "ppo_lag", "multiplier": {"lr": 0.5}, **algo_cfg}, **env)
    batch = col.collect()
    _, pid, pcol = setup({"name": "pid_lag", "multiplier": {"kind": "pid", "ki": 0.5, "kp": 2.0}, **algo_cfg}, **env)
    pbatch = pcol.collect()
    assert torch.equal(batch.get(("next", "cost")), pbatch.get(("next", "cost")))  # same data
    lam_i = lag.update(batch)["lagrange_multiplier"]
    lam_pid = pid.update(pbatch)["lagrange_multiplier"]
    j_c = (lam_i / 0.5) + 0.2  # dual ascent from 0: lambda = lr * (J_c - d)
    assert lam_pid == pytest.approx(lam_i + 2.0 * (j_c - 0.2))
    state = pid.state_dict()
    _, pid2, _ = setup({"name": "pid_lag", "multiplier": {"kind": "pid", "ki": 0.5, "kp": 2.0}, **algo_cfg}, **env)
    pid2.load_state_dict(state)
    assert pid2.multiplier.state_dict() == pid.multiplier.state_dict() and pid2.lagrange_multiplier == lam_pid


def test_nan_loss_stops_the_run_and_keeps_the_last_good_checkpoint(tmp_path, monkeypatch):
    calls = {"n": 0}
    original = PPO.policy_advantage

    def poisoned(self, batch):
        calls["n"] += 1
        adv = original(self, batch)
        return adv * float("nan") if calls["n"] >= 3 else adv

    monkeypatch.setattr(PPO, "policy_advantage", poisoned)
    cfg = load_config(
        {
            "algo": {"name": "ppo", "update_epochs": 1},
            "env": {"num_envs": 2},
            "rollout_steps": 16,
            "total_steps": 320,
            "checkpoint_every": 1,
        }
    )
    with pytest.raises(TrainingDiverged, match="iteration 3: loss_pi is nan.*last good checkpoint"):
        train(cfg, tmp_path, echo=lambda s: None)
    state = load_checkpoint(tmp_path / "checkpoint.pt", algo="ppo", policy="mlp")
    assert state["iteration"] == 2 and state["step"] == 64
    assert all(torch.isfinite(t).all() for t in state["members"][0]["algo_state"]["networks"].values())
    rows = list(csv.DictReader(open(tmp_path / "metrics.csv")))
    assert [r["iteration"] for r in rows] == ["1", "2"]
    assert not (tmp_path / "eval.json").exists()


def test_checkpoint_errors(tmp_path):
    with pytest.raises(CheckpointError, match="no file"):
        load_checkpoint(tmp_path / "missing.pt")
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="corrupt"):
        load_checkpoint(tmp_path / "bad.pt")
    cfg = load_config(
        {
            "algo": {"name": "ppo", "update_epochs": 1},
            "env": {"num_envs": 2},
            "rollout_steps": 16,
            "total_steps": 32,
            "eval_episodes": 2,
        }
    )
    train(cfg, tmp_path, echo=lambda s: None)
    with pytest.raises(CheckpointError, match="algo='ppo'.*algo='ppo_lag'"):
        load_checkpoint(tmp_path / "checkpoint.pt", algo="ppo_lag")


def test_policy_loss_equals_torchrl_clip_ppo_loss():
    """The hand-written clipped surrogate is ClipPPOLoss's, on a TensorDict wrapper of the same actor."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules import IndependentNormal, ProbabilisticActor
    from torchrl.objectives import ClipPPOLoss

    cfg, algo, col = setup({"name": "ppo", "entropy_coef": 0.01, "clip_epsilon": 0.1})
    batch = col.collect()
    algo.gae(batch, algo.agent)
    batch.set(keys.POLICY_ADVANTAGE, batch.get(keys.ADVANTAGE))
    actor = algo.agent.actor
    with torch.no_grad():  # move the policy so that ratios differ from 1 and some are clipped
        for p in actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    flat = batch.reshape(-1)

    class Params(torch.nn.Module):
        def forward(self, obs):
            return tuple(actor.params({keys.OBS: obs}).values())

    td_actor = ProbabilisticActor(
        TensorDictModule(Params(), [keys.OBS], [keys.LOC, keys.SCALE]),
        in_keys=[keys.LOC, keys.SCALE],
        out_keys=[keys.ACTION],
        distribution_class=IndependentNormal,
        return_log_prob=True,
        log_prob_key=keys.LOG_PROB,
    )
    ref = ClipPPOLoss(td_actor, critic_network=None, clip_epsilon=0.1, entropy_coeff=0.01, normalize_advantage=False)
    ref.set_keys(advantage=keys.POLICY_ADVANTAGE, sample_log_prob=keys.LOG_PROB)
    out = ref(flat)
    mb = {k: flat.get(k) for k in algo.update_keys(batch)}
    dist = algo.agent.dist(mb)
    terms, diagnostics = algo.policy_terms(dist, mb)  # per sample, reduced as a run's update does
    entropy = dist.entropy().mean()
    loss = terms.mean() - 0.01 * entropy
    stats = {k: v.mean() for k, v in diagnostics.items()}
    assert torch.allclose(loss, out["loss_objective"] + out["loss_entropy"], rtol=1e-6, atol=1e-7)
    assert torch.allclose(entropy, out["entropy"]) and torch.allclose(stats["kl"], out["kl_approx"])
    assert stats["clip_fraction"] == out["clip_fraction"] and 0.05 < stats["clip_fraction"].item() < 0.95


def test_kl_early_stopping_stops_the_update_at_the_first_minibatch_past_1_5_target_kl():
    """With a tiny target_kl the first minibatch (ratio 1, KL 0) steps, the second is past
    1.5 * target_kl and stops the update: the policy moved once; with target_kl=None, all 4 steps."""
    steps = {}
    for target in (1e-12, None):
        cfg, algo, col = setup(
            {"name": "ppo", "update_epochs": 2, "num_minibatches": 2, "target_kl": target, "lr": 1e-2}
        )
        algo.update(col.collect())
        # Adam's own count of the steps it took (each parameter's "step"), whichever path stepped it.
        counts = {int(algo.actor_opt.state[p]["step"]) for p in algo.actor_params}
        assert len(counts) == 1
        steps[target] = counts.pop()
    assert steps == {1e-12: 1, None: 4}


def test_fast_tanh_matches_torch_tanh_and_its_gradient():
    from cmdp_rl.policies.mlp import Tanh

    x = torch.linspace(-12, 12, 4 * Tanh.MIN_NUMEL + 1, requires_grad=True)  # large: the sigmoid form
    y = Tanh()(x)
    assert not torch.equal(y, torch.tanh(x))  # (it is not torch.tanh's own kernel)
    assert (y - torch.tanh(x)).abs().max().item() < 3e-7 and y.min() == -1 and y.max() == 1
    (g,) = torch.autograd.grad(y.sum(), x)
    assert torch.allclose(g, 1 - torch.tanh(x.detach()) ** 2, atol=1e-6)
    with torch.no_grad():
        assert torch.equal(Tanh()(x), y.detach())


def test_a_non_finite_parameter_after_a_finite_loss_stops_the_run(tmp_path, monkeypatch):
    from cmdp_rl.algos import learner

    calls = {"n": 0}
    original = learner.adam_step

    def step_then_break(opt):
        original(opt)
        calls["n"] += 1
        # the last step of iteration 3 (2 minibatches x 2 optimizers per iteration, the critics' second)
        if calls["n"] == 2 * 2 * 3:
            with torch.no_grad():
                opt.param_groups[0]["params"][0].fill_(float("inf"))  # the reward critic's first weight

    monkeypatch.setattr(learner, "adam_step", step_then_break)
    cfg = load_config(
        {
            "algo": {"name": "ppo", "update_epochs": 1, "num_minibatches": 2},
            "env": {"num_envs": 2},
            "rollout_steps": 16,
            "total_steps": 320,
            "checkpoint_every": 1,
        }
    )
    with pytest.raises(TrainingDiverged, match=r"iteration 3: parameter critics\.reward\.net\.0\.weight is not finite"):
        train(cfg, tmp_path, echo=lambda s: None)
    state = load_checkpoint(tmp_path / "checkpoint.pt", algo="ppo")
    assert state["iteration"] == 2
    assert all(torch.isfinite(t).all() for t in state["members"][0]["algo_state"]["networks"].values())


def test_anneal_lr_scales_the_rates_linearly_to_zero_over_the_run():
    # 4 iterations of 2 x 32 steps: iteration i updates with 1 - i/4 of lr and critic_lr; lambda's step
    # is not annealed (the multiplier's lr stays 0.5).
    algo_cfg = {
        "name": "ppo_lag",
        "lr": 1e-3,
        "critic_lr": 2e-3,
        "multiplier": {"kind": "dual", "lr": 0.5, "scale": "none"},  # the step below in the cost's own units
        "update_epochs": 1,
        "cost_limit": 0.2,
        "anneal_lr": True,
    }
    cfg = load_config(
        {
            "algo": algo_cfg,
            "env": {"num_envs": 2, "max_steps": 3, "wall": "pass", "start": 0.45},
            "rollout_steps": 32,
            "total_steps": 200,
        }
    )
    assert cfg.algo.anneal_lr == 4  # true: over the run's iterations, ceil(200 / 64)
    torch.manual_seed(0)
    e = make_env(cfg.env)
    lag = make_algo(cfg.algo, make_agent(cfg.policy, e))
    col = Collector(e, lag.agent, cfg.rollout_steps, seed=0)
    for i, frac in enumerate([1.0, 0.75, 0.5, 0.25]):
        before = lag.lagrange_multiplier
        batch = col.collect()
        saved = copy.deepcopy(lag.episode_cost.state_dict())
        cost = lag.episode_cost.update(batch).costs[0]  # the J_c that update() will measure
        lag.episode_cost.load_state_dict(saved)
        lag.update(batch)
        assert lag.actor_opt.param_groups[0]["lr"] == pytest.approx(frac * 1e-3)
        assert lag.critic_opt.param_groups[0]["lr"] == pytest.approx(frac * 2e-3)
        assert lag.lagrange_multiplier == pytest.approx(max(0.0, before + 0.5 * (cost - 0.2)))
    assert lag.state_dict()["iteration"] == 4
    # Off (the default): the rates stay as given.
    _, plain, col = setup({"name": "ppo_lag", "update_epochs": 1})
    assert plain.cfg.anneal_lr is False
    plain.update(col.collect())
    plain.update(col.collect())
    assert plain.actor_opt.param_groups[0]["lr"] == plain.cfg.lr
    assert plain.multiplier.controllers[0].lr == plain.cfg.multiplier.lr


def test_anneal_lr_spans_the_iterations_it_names_and_a_bad_span_is_named():
    """``anneal_lr: n`` anneals over n iterations (the rates reach 0 at iteration n and stay there); old configs
    named the span apart, ``anneal_iterations``, read only when ``anneal_lr`` was true."""
    _, lag, col = setup({"name": "ppo_lag", "update_epochs": 1, "lr": 1e-3, "anneal_lr": 2})
    rates = []
    for _ in range(3):
        lag.update(col.collect())
        rates.append(lag.actor_opt.param_groups[0]["lr"])
    assert rates == pytest.approx([1e-3, 0.5e-3, 0.0])
    with pytest.raises(ConfigError, match="algo.anneal_lr"):
        load_config({"algo": {"name": "ppo", "anneal_lr": 0}})
    old = {"algo": {"name": "ppo_lag", "anneal_lr": True, "anneal_iterations": 7}}
    assert load_config(saved_config_nodes(old)).algo.anneal_lr == 7
    old["algo"]["anneal_lr"] = False
    assert load_config(saved_config_nodes(old)).algo.anneal_lr is False
