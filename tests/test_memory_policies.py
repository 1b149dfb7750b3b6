"""History-dependent policies: recurrent step mode equals recurrent mode, states reset at episode
starts, the value pass is the step-by-step one, the transformer's carried window equals the
explicit window, the collector's previous action/cost, and acting equals the training pass."""

import gymnasium as gym
import numpy as np
import pytest
import torch

from cmdp_rl import Collector, keys, load_config, make_agent, make_env
from cmdp_rl.config.run_config import ConfigError

# Short episodes (7 steps) over 20-step rollouts: episodes start mid-batch and span batches.
ENV = {"num_envs": 4, "max_steps": 7, "probe": True, "start": [0.0, 0.8], "backend": "torch", "obs_noise": 0.1}


def setup(policy: dict, rollout: int = 20, seed: int = 0):
    cfg = load_config({"policy": policy, "env": ENV, "rollout_steps": rollout, "algo": {"num_minibatches": 2}})
    env = make_env(cfg.env)
    torch.manual_seed(seed)
    ac = make_agent(cfg.policy, env)
    return ac, Collector(env, ac, rollout, seed=seed)


def second_batch(col):
    """A batch that starts mid-episode, with stored states from the previous batch."""
    col.collect()
    b = col.collect()
    assert not b[keys.IS_INIT][:, 0].all() and b[keys.IS_INIT][:, 1:].any()
    return b


def actor_units(ac, b):
    return ac.training_units({k: b.get(k) for k in [*ac.actor.body.in_keys, keys.ACTION]})


def recurrent_log_probs(ac, b):
    """The training pass (``Agent.dist`` on the batch's training units) on the rollout's steps."""
    data = actor_units(ac, b)
    with torch.no_grad():
        dist = ac.dist(data)
    return (
        dist.log_prob(data[keys.ACTION]),
        dist.mean,
        ac.training_units({keys.LOG_PROB: b[keys.LOG_PROB], keys.LOC: b[keys.LOC]}),
    )


def step_mode_log_prob(ac, data):
    """The actor run one step at a time (acting's ``Body.step``) on every unit's steps, each from
    the state stored with it."""
    flat = {k: v.flatten(0, 1) for k, v in data.items()}
    with torch.no_grad():
        features, _ = ac.actor.body.step(flat)
        dist = ac.actor.head.dist(ac.actor.head(*features))
    return dist.log_prob(flat[keys.ACTION]).unflatten(0, data[keys.ACTION].shape[:2])


@pytest.mark.parametrize("name", ["lstm", "gru"])
@pytest.mark.parametrize("segment", [0, 5])
def test_recurrent_policy_step_by_step_equals_recurrent_mode(name, segment):
    """The rollout's log-probs (one step at a time, state carried) are recomputed in recurrent mode
    over whole rows or 5-step segments, each started from its stored state."""
    ac, col = setup({"name": name, "segment_length": segment})
    b = second_batch(col)
    log_prob, loc, stored = recurrent_log_probs(ac, b)
    assert log_prob.shape == stored[keys.LOG_PROB].shape == ((4, 20) if segment == 0 else (16, 5))
    assert torch.allclose(log_prob, stored[keys.LOG_PROB], atol=1e-5)
    assert torch.allclose(loc, stored[keys.LOC], atol=1e-6)
    # Recurrent mode really runs through time: garbage stored states inside a segment (not at its
    # start, not at an episode start) change nothing ...
    data = actor_units(ac, b)
    # step mode on the stored states gives the rollout's log-probs too ...
    assert torch.allclose(step_mode_log_prob(ac, data), stored[keys.LOG_PROB], atol=1e-5)
    keep = data[keys.IS_INIT].squeeze(-1).clone()
    keep[:, 0] = True
    for k in (keys.ACTOR_HIDDEN, keys.ACTOR_CELL):
        if k in data:
            data[k] = torch.where(keep[..., None, None], data[k], torch.randn_like(data[k]) * 5)
    with torch.no_grad():
        assert torch.allclose(ac.dist(data).log_prob(data[keys.ACTION]), stored[keys.LOG_PROB], atol=1e-5)
    # ... whereas step mode reads them.
    assert not torch.allclose(step_mode_log_prob(ac, data), stored[keys.LOG_PROB], atol=1e-3)


@pytest.mark.parametrize("name", ["lstm", "gru"])
def test_recurrent_state_resets_where_an_episode_starts_mid_batch(name):
    ac, col = setup({"name": name, "segment_length": 0})
    b = second_batch(col)
    is_init = b[keys.IS_INIT].squeeze(-1)
    # The collector stores the initial (zero) state at every episode start, as torchrl's primer.
    for k in (keys.ACTOR_HIDDEN, keys.CRITIC_HIDDEN, keys.COST_CRITIC_HIDDEN):
        assert (b[k][is_init] == 0).all() and (b[k][~is_init] != 0).any()
    row, t = next((i, t) for i, t in is_init.nonzero().tolist() if t > 0)
    in_keys = ac.actor.body.in_keys
    with torch.no_grad():
        full = ac.dist({k: b[k][row : row + 1] for k in in_keys}).mean
        # The episode alone, from a zero state ...
        alone = {k: b[k][row : row + 1, t:] for k in in_keys}
        for k in (keys.ACTOR_HIDDEN, keys.ACTOR_CELL):
            if k in alone:
                alone[k] = torch.zeros_like(alone[k])
        loc_alone = ac.dist(alone).mean
        # ... and the row with the steps before it scrambled: the new episode does not see them.
        scrambled = {k: b[k][row : row + 1].clone() for k in in_keys}
        scrambled[keys.OBS][:, :t] = torch.rand_like(scrambled[keys.OBS][:, :t])
        scrambled[keys.PREV_ACTION][:, :t] = torch.rand_like(scrambled[keys.PREV_ACTION][:, :t])
        loc_scrambled = ac.dist(scrambled).mean
    assert torch.allclose(full[:, t:], loc_alone, atol=1e-6)
    assert torch.allclose(full[:, t:], loc_scrambled[:, t:], atol=1e-6)
    assert not torch.allclose(full[:, :t], loc_scrambled[:, :t], atol=1e-4)


@pytest.mark.parametrize("policy", [{"name": "lstm"}, {"name": "gru"}, {"name": "transformer", "window": 4}])
@pytest.mark.parametrize("signal", ["reward", "cost"])
def test_value_pass_equals_the_critic_stepped_through_the_rollout(policy, signal):
    """Root values are the critic's stepwise values; next values at episode ends and the last step
    are one more critic step from the state after that step, on the final observation."""
    ac, col = setup({**policy, **({"segment_length": 0} if policy["name"] != "transformer" else {})})
    b = second_batch(col)
    critic = ac.critics[signal]
    with torch.no_grad():
        values, next_values = ac.rollout_values(b, signal)
        # The critic stepped through the rollout, one step at a time from the state stored at
        # each step (the collector stepped it too: its state at every step is in the batch).
        stepped = torch.stack([critic.step({k: b[k][:, t] for k in critic.body.in_keys}) for t in range(20)], dim=1)
        assert values.shape == next_values.shape == (4, 20, 1)
        assert torch.allclose(values, stepped, atol=1e-5)
        fresh = b[keys.NEXT][keys.DONE].squeeze(-1).clone()
        fresh[:, -1] = True
        assert torch.equal(next_values[:, :-1][~fresh[:, :-1]], values[:, 1:][~fresh[:, :-1]])
        nxt = {k: b[keys.NEXT][k][fresh] for k in critic.body.in_keys if k != keys.IS_INIT}
        nxt[keys.IS_INIT] = torch.zeros(int(fresh.sum()), 1, dtype=torch.bool)
        expected = critic.step(nxt)
        # at an episode end the next value is not the following step's (a new episode's reset one)
        ends = b[keys.NEXT][keys.DONE].squeeze(-1)[:, :-1]
        assert not torch.allclose(next_values[:, :-1][ends], values[:, 1:][ends], atol=1e-4)
    assert torch.allclose(next_values[fresh], expected, atol=1e-5)


@pytest.mark.parametrize("positions", ["learned", "sinusoidal"])
def test_transformer_incremental_equals_the_explicit_window(positions):
    """The window carried step by step gives the same action distribution as the transformer run
    on the last K steps of the trajectory, cut at the episode's start."""
    K = 4
    ac, col = setup({"name": "transformer", "window": K, "layers": 2, "positions": positions})
    b = col.collect()  # from reset: every row starts an episode at t = 0
    tokens = torch.cat([b[keys.OBS], b[keys.PREV_ACTION], b[keys.PREV_COST]], dim=-1)
    is_init = b[keys.IS_INIT].squeeze(-1)
    head = ac.actor.head  # the transformer and its MLP, then the Gaussian's parameters
    windows, masks = [], []
    for i in range(4):
        start = 0
        for t in range(20):
            if is_init[i, t]:
                start = t
            w = torch.zeros(K, tokens.shape[-1])
            m = torch.zeros(K, dtype=torch.bool)
            for j, s in enumerate(range(t - K + 1, t + 1)):
                if s >= start:
                    w[j], m[j] = tokens[i, s], True
            windows.append(w)
            masks.append(m)
    with torch.no_grad():
        params = head(torch.stack(windows), torch.stack(masks))
    loc, scale = params[keys.LOC], params[keys.SCALE]
    assert torch.allclose(loc, b[keys.LOC].reshape(-1, loc.shape[-1]), atol=1e-5)
    assert torch.allclose(scale, b[keys.SCALE].reshape(-1, loc.shape[-1]))


def test_transformer_last_query_equals_the_full_layer():
    from cmdp_rl.policies.inputs import InputEncoder
    from cmdp_rl.policies.transformer import TransformerPolicyConfig, WindowTransformer

    torch.manual_seed(0)
    cfg = TransformerPolicyConfig(window=6, layers=2, heads=2, width=8, feedforward=16)
    net = WindowTransformer(cfg, InputEncoder(2, gym.spaces.Box(-0.1, 0.1, (1,), np.float32), True, True), 2)
    w, m = torch.randn(5, 6, 4), torch.rand(5, 6) > 0.4
    m[:, -1] = True
    x = net.embed(net._split(w)) + net.positions
    blocked = (~((net.causal & m.unsqueeze(-2)) | net.eye)).repeat_interleave(2, dim=0)
    for layer in (*net.context, net.last):
        x = layer(x, src_mask=blocked)
    assert torch.allclose(net(w, m), net.norm(x[:, -1]), atol=1e-5)
    # a padded (pre-episode) step does not influence the output
    w2 = w.clone()
    w2[~m] = torch.randn_like(w2[~m]) * 10
    assert torch.allclose(net(w, m), net(w2, m), atol=1e-5)


def test_collector_writes_previous_action_and_cost():
    ac, col = setup({"name": "mlp", "include_prev_action": True, "include_prev_cost": True})
    b = second_batch(col)
    is_init = b[keys.IS_INIT]
    for prev, now in ((keys.PREV_ACTION, b[keys.ACTION]), (keys.PREV_COST, b[keys.NEXT][keys.COST])):
        assert torch.equal(b[keys.NEXT][prev], now)
        expected = torch.where(is_init[:, 1:], torch.zeros_like(now[:, :-1]), now[:, :-1])
        assert torch.equal(b[prev][:, 1:], expected)
        assert (b[prev][is_init.squeeze(-1)] == 0).all()
    assert (b[keys.PREV_COST] != 0).any() or (b[keys.NEXT][keys.COST][:, :-1] == 0).all()


@pytest.mark.parametrize(
    "policy",
    [
        {"name": "lstm", "segment_length": 5},
        {"name": "transformer"},
        {"name": "mlp", "include_prev_action": True, "include_prev_cost": True},
    ],
)
def test_acting_equals_the_training_pass(policy):
    """One execution path: the distribution the agent acted from, step by step with its carried
    state (the collector), is the one the training pass gives on the batch's training units
    (recurrent segments from their stored states, the transformer's stored windows, single steps);
    and a collector on the same seed and parameters repeats the batch exactly."""
    ac, col = setup(policy)
    a = second_batch(col)
    ac2, col2 = setup(policy, seed=0)
    ac2.load_state_dict(ac.state_dict())
    assert (second_batch(col2) == a).all()
    data = actor_units(ac, a)
    stored = ac.training_units({k: a[k] for k in (keys.LOG_PROB, keys.LOC, keys.SCALE)})
    with torch.no_grad():
        dist = ac.dist(data)
    assert torch.allclose(dist.mean, stored[keys.LOC], atol=1e-6)
    assert torch.allclose(dist.stddev, stored[keys.SCALE])
    assert torch.allclose(dist.log_prob(data[keys.ACTION]), stored[keys.LOG_PROB], atol=1e-5)


@pytest.mark.parametrize(
    "overrides,message",
    [
        (
            {"policy": {"name": "lstm", "segment_length": 7}},
            "policy.segment_length must be 0 or >= rollout_steps (whole rollouts), or a divisor of rollout_steps=64",
        ),
        (
            {"policy": {"name": "lstm", "segment_length": 0}, "env": {"num_envs": 2}, "algo": {"num_minibatches": 4}},
            "algo.num_minibatches must be at most the number of training segments",
        ),
        (
            {"policy": {"name": "transformer", "width": 30, "heads": 4}},
            "policy.width must be a positive multiple of policy.heads=4",
        ),
        ({"policy": {"name": "transformer", "positions": "rotary"}}, "policy.positions must be one of"),
        ({"policy": {"name": "lstm", "window": 8}}, "policy: unknown option(s) ['window']"),
        ({"policy": {"name": "rnn"}}, "policy.name: unknown policy 'rnn'"),
    ],
)
def test_bad_policy_options_are_named(overrides, message):
    with pytest.raises(ConfigError) as err:
        load_config({"rollout_steps": 64, **overrides})
    assert message in str(err.value)
