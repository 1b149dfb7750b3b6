"""Both GAEs against closed-form values: no end, truncation (bootstrap), termination (no bootstrap)."""

import pytest
import torch
from tensordict import TensorDict

from cmdp_rl import keys
from cmdp_rl.policies import Agent, Critic
from cmdp_rl.policies.mlp import MLPBody
from cmdp_rl.rollout.advantages import TwinGAE

GAMMA, LAM = 0.9, 0.8
V = [0.5, 0.2, 0.1]  # V(s_0..s_2)
V_NEXT = [0.2, 0.1, 0.3]  # V(s_1..s_3); the critic's value of each step's next observation
R = [1.0, 0.0, 2.0]
C = [0.0, 1.0, 1.0]


class Lookup(torch.nn.Module):
    """A 'critic' returning a fixed value per observation index, so GAE sees known values."""

    def __init__(self, table):
        super().__init__()
        self.table = table

    def forward(self, obs):
        return self.table[obs[..., 0].long()].unsqueeze(-1)


def batch(terminated_at=None, truncated_at=None):
    # observations are indices into the value tables: step t sees obs t, its next obs is t + 1
    obs = torch.tensor([[[0.0], [1.0], [2.0]]])
    nxt = torch.tensor([[[1.0], [2.0], [3.0]]])
    term = torch.zeros(1, 3, 1, dtype=torch.bool)
    trunc = torch.zeros(1, 3, 1, dtype=torch.bool)
    if terminated_at is not None:
        term[0, terminated_at] = True
    if truncated_at is not None:
        trunc[0, truncated_at] = True
    return TensorDict(
        {
            keys.OBS: obs,
            keys.NEXT: {
                keys.OBS: nxt,
                keys.REWARD: torch.tensor(R).view(1, 3, 1),
                keys.COST: torch.tensor(C).view(1, 3, 1),
                keys.TERMINATED: term,
                keys.TRUNCATED: trunc,
                keys.DONE: term | trunc,
            },
        },
        batch_size=[1, 3],
    )


def closed_form(signal, done_at=None, terminal=False):
    """A_t = delta_t + gamma*lambda*A_{t+1}, delta_t = s_t + gamma*V(s_{t+1})*(1-term_t) - V(s_t);
    the recursion stops at an episode end; the bootstrap stops only at termination."""
    adv = [0.0] * 3
    nxt_adv = 0.0
    for t in reversed(range(3)):
        boot = 0.0 if (terminal and t == done_at) else GAMMA * V_NEXT[t]
        delta = signal[t] + boot - V[t]
        carry = 0.0 if t == done_at else GAMMA * LAM * nxt_adv
        adv[t] = delta + carry
        nxt_adv = adv[t]
    return adv


def critics():
    """Both critics, on the observation, in an Agent (the actor is not used by GAE)."""
    table = torch.tensor(V + [V_NEXT[-1]])
    return Agent(
        actor=None, critics={signal: Critic(MLPBody(None, None), Lookup(table)) for signal in ("reward", "cost")}
    )


@pytest.mark.parametrize("case", ["none", "truncated", "terminated"])
def test_twin_gae_matches_closed_form(case):
    kw = {"truncated": dict(truncated_at=1), "terminated": dict(terminated_at=1)}.get(case, {})
    b = batch(**kw)
    TwinGAE(GAMMA, GAMMA, LAM)(b, critics())
    done_at = 1 if case != "none" else None
    for sig, adv_key, tgt_key in (
        (R, keys.ADVANTAGE, keys.VALUE_TARGET),
        (C, keys.COST_ADVANTAGE, keys.COST_VALUE_TARGET),
    ):
        expected = torch.tensor(closed_form(sig, done_at, terminal=case == "terminated"))
        assert torch.allclose(b[adv_key].view(-1), expected, atol=1e-6), (case, adv_key)
        assert torch.allclose(b[tgt_key].view(-1), expected + torch.tensor(V), atol=1e-6)


def test_hand_numbers_for_the_no_end_case():
    # written out once so the closed form itself is checked: A_2 = 2 + .9*.3 - .1 = 2.17, ...
    assert closed_form(R) == pytest.approx([1.725728, 1.4524, 2.17])
    assert closed_form(R, 1, terminal=False) == pytest.approx([0.6008, -0.11, 2.17])
    assert closed_form(R, 1, terminal=True) == pytest.approx([0.536, -0.2, 2.17])


@pytest.mark.parametrize("chunk_rows", [8192, 100])
def test_critic_values_of_a_collector_batch_equal_a_full_evaluation(chunk_rows, monkeypatch):
    """Agent.rollout_values evaluates V(next obs) only at episode ends and the last step (and in
    chunks of CHUNK_ROWS rows); the values are those of evaluating the critic on every observation
    and every next observation."""
    from cmdp_rl import Collector, load_config, make_agent, make_env
    from cmdp_rl.policies import agent as agent_module

    monkeypatch.setattr(agent_module, "CHUNK_ROWS", chunk_rows)

    cfg = load_config({"env": {"backend": "torch", "num_envs": 16, "max_steps": 7, "start": [0.0, 0.8]}})
    env = make_env(cfg.env)
    torch.manual_seed(0)
    ac = make_agent(cfg.policy, env)
    b = Collector(env, ac, 30, seed=0).collect()
    assert b[keys.NEXT][keys.DONE].any()
    for signal in ("reward", "cost"):
        with torch.no_grad():
            values, next_values = ac.rollout_values(b, signal)
            full_now = ac.critics[signal].net(b[keys.OBS])
            full_next = ac.critics[signal].net(b[keys.NEXT][keys.OBS])
        assert values.shape == next_values.shape == (16, 30, 1)
        assert torch.allclose(values, full_now, atol=1e-6)
        assert torch.allclose(next_values, full_next, atol=1e-6)
    assert not torch.allclose(ac.critics["reward"].net(b[keys.OBS]), ac.critics["cost"].net(b[keys.OBS]))
