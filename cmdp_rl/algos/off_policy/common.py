"""What SAC(-Lagrangian) and TD3(-Lagrangian) share: the replay buffer, target networks, the TD targets of
the twin reward critics and the cost critic, the multiplier on the cost critic, and the update loop: each
short rollout (``rollout_steps: auto``) joins the buffer, then ``utd_ratio`` gradient steps per transition
once it holds ``warmup_steps`` (the collector acts uniformly at random until then).

The multiplier compares ``E_s[Q_c(s, pi(s))]`` over the newest ``cost_window`` transitions' states (not the
replayed ones, mostly older policies': on HalfCheetah lambda drifted down over budget, docs/off_policy.md)
with :func:`discounted_budget` ``= d (1 - gamma^T) / (T (1 - gamma))``, the episode budget spent evenly over
T steps on the discounted scale (the conversion of Safety-Starter-Agents' SAC-Lagrangian and WCSAC).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal, Union

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torchrl.data import LazyMemmapStorage, LazyTensorStorage, TensorDictReplayBuffer

from cmdp_rl.algos.base import AlgoConfig, check_finite, check_parameters_finite, per_constraint
from cmdp_rl.algos.multiplier import Multipliers, logged_multiplier
from cmdp_rl.algos.multiplier_options import DualOptions, QMultiplierConfig
from cmdp_rl.config.validation import AUTO, Field, NonNegativeInt, PositiveFloat, PositiveInt, finite, options, require
from cmdp_rl.policies.agent import Agent
from cmdp_rl.policies.squashed import Q_COST, Q_REWARD, check_off_policy_agent, check_shaped, to_off_policy
from cmdp_rl.rollout import keys

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig


# --- The replay buffer and the target networks ---------------------------------------------
# What a transition keeps in the buffer: reward and cost are twins, as in the batch. A truncated
# step keeps its final observation under "next" and bootstraps from it (only termination masks).
STORED = (keys.OBS, keys.ACTION, *((keys.NEXT, k) for k in (keys.OBS, keys.REWARD, keys.COST, keys.TERMINATED)))


class Replay:
    """torchrl's ``TensorDictReplayBuffer`` of single transitions, sampled with torch's (seeded) generator."""

    def __init__(self, size: int, batch_size: int, storage: str, device: torch.device | str = "cpu") -> None:
        store = (
            LazyMemmapStorage(size, device=device) if storage == "memmap" else LazyTensorStorage(size, device=device)
        )
        self.buffer = TensorDictReplayBuffer(storage=store, batch_size=batch_size)

    def __len__(self) -> int:
        return len(self.buffer)

    def add(self, batch: TensorDictBase) -> int:
        """Add the ``[N, T]`` batch's transitions; returns how many."""
        flat = batch.select(*STORED).reshape(-1)
        self.buffer.extend(flat)
        return flat.shape[0]

    def sample(self) -> TensorDictBase:
        return self.buffer.sample()

    def newest(self, n: int) -> TensorDictBase:
        """The ``n`` transitions added last, oldest first: they end just before the writer's cursor."""
        n = min(n, len(self.buffer))
        cursor = self.buffer.writer.state_dict()["_cursor"]
        return self.buffer.storage.get((cursor - n + torch.arange(n)) % self.buffer.storage.max_size)

    def state_dict(self) -> dict:
        """The stored transitions in storage order (only the filled rows, not the whole capacity)
        and the writer's cursor: a buffer loading it samples the same indices to the same data."""
        n = len(self.buffer)
        data = self.buffer.storage.get(torch.arange(n)).to_dict() if n else {}
        return {"data": data, "len": n, "writer": self.buffer.writer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        if state["len"]:
            self.buffer.extend(TensorDict(state["data"], batch_size=[state["len"]]))
        self.buffer.writer.load_state_dict(state["writer"])


class TargetCritics:
    """Slow copies of critics' output networks (their body has no parameters), moved by Polyak averaging."""

    def __init__(self, modules: dict[str, nn.Module]) -> None:
        self.target = {k: copy.deepcopy(m).requires_grad_(False) for k, m in modules.items()}
        # Listed once (load_state_dict copies into these tensors): one lerp over all of them a step.
        self._pairs = (
            [p for k in modules for p in self.target[k].parameters()],
            [p for m in modules.values() for p in m.parameters()],
        )

    @torch.no_grad()
    def soft_update(self, tau: float) -> None:
        """``theta' <- tau theta + (1 - tau) theta'`` (Haarnoja et al. 2018b; Fujimoto et al. 2018)."""
        torch._foreach_lerp_(*self._pairs, tau)

    def state_dict(self) -> dict:
        return {k: m.state_dict() for k, m in self.target.items()}

    def load_state_dict(self, state: dict) -> None:
        for k, m in self.target.items():
            m.load_state_dict(state[k])


def td_target(signal: torch.Tensor, terminated: torch.Tensor, gamma: float, next_value: torch.Tensor) -> torch.Tensor:
    """One-step TD target ``x + gamma (1 - terminated) V'``: a truncated step bootstraps."""
    return signal + gamma * (~terminated).float() * next_value


# --- Options, and the update ----------------------------------------------------------------
def discounted_budget(d: float, gamma: float, episode_length: int) -> float:
    """The episode budget ``d`` on a cost Q-critic's discounted scale (module docstring)."""
    T = episode_length
    return d * (1.0 - gamma**T) / (T * (1.0 - gamma))


@dataclass
class LagrangeFields:
    """The multiplier of the ``_lag`` variants (mixed into their options)."""

    # On the violation Q_c - d_Q; off-policy defaults: a step of 0.01, for kind: pid the integral alone.
    multiplier: QMultiplierConfig = field(default_factory=lambda: DualOptions(lr=0.01))
    # Q_c is averaged over the newest cost_window transitions' states; 0: over the replayed minibatches'.
    cost_window: NonNegativeInt = 1000
    # T of the budget conversion: "auto" reads the env's time limit (env.max_steps).
    episode_length: Annotated[
        Union[PositiveInt, Literal["auto"]], Field(description="a positive integer or 'auto'")
    ] = AUTO


@options
class OffPolicyConfig(AlgoConfig):
    """Options of every off-policy algorithm (gae_lambda, normalize_advantage, max_grad_norm: unread)."""

    name: str = "sac"
    tiny: ClassVar[dict] = {"warmup_steps": 16, "batch_size": 16, "buffer_size": 1000, "utd_ratio": 0.25}
    actor_head: ClassVar[str] = "tanh_gaussian"  # the actor it trains (policies/squashed.py); TD3: deterministic
    lr: PositiveFloat = 3e-4  # actor
    critic_lr: PositiveFloat = 3e-4
    utd_ratio: Annotated[float, finite(gt=0, le=64)] = 1.0  # gradient steps per collected transition
    warmup_steps: NonNegativeInt = 5000  # transitions (uniformly random actions) before the first update
    batch_size: PositiveInt = 256
    buffer_size: PositiveInt = 1_000_000
    storage: Literal["memory", "memmap"] = "memory"  # memmap: torchrl's LazyMemmapStorage on disk
    tau: Annotated[float, finite(gt=0, le=1)] = 0.005  # Polyak step of the target critics

    @property
    def uniform_action_steps(self) -> int:
        return self.warmup_steps  # its warm-up

    def shape_agent(self, agent: Agent) -> Agent:
        check_off_policy_agent(agent, self.name)  # a squashed actor and Q-critics on the policy's MLP body
        return to_off_policy(agent, self.actor_head, getattr(self, "exploration_noise", 0.1))

    def auto_rollout_steps(self, run: RunConfig) -> int:
        """``rollout_steps: auto``: about 64 transitions per iteration (8 steps of 8 envs)."""
        return max(1, 64 // run.env.num_envs)

    def resolve_auto(self, run: RunConfig) -> None:
        if getattr(self, "episode_length", None) == AUTO:
            T = getattr(run.env, "max_steps", None)
            require(
                T is not None,
                "algo.episode_length",
                f"a positive integer for env={run.env.name} (it has no max_steps to read)",
                AUTO,
            )
            self.episode_length = int(T)

    def describe_update(self) -> str:
        return (
            f"{self.utd_ratio:g} gradient steps per transition on batches of {self.batch_size} "
            f"after {self.warmup_steps} warm-up steps"
        )

    def check(self, run: RunConfig) -> None:
        require(
            run.policy.name == "mlp",
            "policy",
            f"mlp for algo={self.name} (recurrent and transformer policies are not supported off-policy)",
            run.policy.name,
        )
        require(
            self.buffer_size >= self.batch_size,
            "algo.buffer_size",
            f">= algo.batch_size ({self.batch_size})",
            self.buffer_size,
        )
        if isinstance(self, LagrangeFields):
            self.multiplier.check()


STATS = ("loss_q", "loss_qc", "loss_pi", "q_reward", "q_cost", "gradient_steps", "buffer_size")


class OffPolicy:
    """The update loop, replay, targets and checkpointing; an algorithm adds the three methods below."""

    stats = STATS

    def __init__(self, cfg: OffPolicyConfig, agent: Agent) -> None:
        check_shaped(agent, cfg.name)
        self.cfg, self.agent = cfg, agent
        device = agent.actor.head.low.device
        self.replay = Replay(cfg.buffer_size, cfg.batch_size, cfg.storage, device)
        limits = per_constraint(cfg.cost_limit, "algo.cost_limit", agent.cost_names)
        self.num_costs, self.multiplier = len(limits), None
        if isinstance(cfg, LagrangeFields):  # lambda per constraint on Q_c against the discounted budget
            self.budgets = [discounted_budget(d, cfg.cost_gamma, cfg.episode_length) for d in limits]
            self.multiplier = Multipliers(cfg.multiplier.build, self.budgets)
        self.targets = TargetCritics({name: agent.critics[name].net for name in (*Q_REWARD, Q_COST)})
        self.actor_params = list(agent.actor.parameters())
        self.critic_params = list(agent.critics.parameters())
        self.actor_opt = torch.optim.Adam(self.actor_params, lr=cfg.lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=cfg.critic_lr, fused=True)
        self.steps_due = 0.0  # fractional gradient steps carried over (utd_ratio < 1)
        self.gradient_steps = 0

    @property
    def lambdas(self) -> list[float]:
        return [0.0] * self.num_costs if self.multiplier is None else self.multiplier.values

    # The critics' output networks are called on inputs prepared once per gradient step, not through
    # Critic/QBody per call (docs/off_policy.md, "Speed").
    def features(self, obs: torch.Tensor) -> torch.Tensor:
        """The observation as the actor's body (and every Q-critic's) prepares it."""
        return self.agent.actor.body({keys.OBS: obs})[0]

    def scaled(self, action: torch.Tensor) -> torch.Tensor:
        """An env-unit action in the critics' [-1, 1] units (QBody's scaling)."""
        body = self.agent.critics[Q_COST].body
        return (action - body.center) / body.half_width

    def q_values(
        self, names: tuple[str, ...], x: torch.Tensor, a: torch.Tensor, target: bool = False
    ) -> list[torch.Tensor]:
        """``Q_n(s, a)`` of each critic in ``names`` (live or target) on features ``x`` and a scaled action."""
        h = torch.cat([x, a], dim=-1)
        nets = self.targets.target if target else {n: self.agent.critics[n].net for n in names}
        return [nets[n](h) for n in names]

    def critic_loss(
        self, mb: TensorDictBase, x: torch.Tensor | None = None, x_next: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Both reward twins and the cost critic regress on one-step TD targets with the algorithm's next
        action a': ``r + gamma (1 - term) (min_j Q'_j(s', a') + bonus)`` and ``c + gamma_c (1 - term)
        Q'_c(s', a')`` (Haarnoja et al. 2018b eq. 5; Fujimoto et al. 2018 eq. 10). ``x``, ``x_next``: the
        observation features, if already computed."""
        cfg = self.cfg
        x = self.features(mb.get(keys.OBS)) if x is None else x
        x_next = self.features(mb.get((keys.NEXT, keys.OBS))) if x_next is None else x_next
        term = mb.get((keys.NEXT, keys.TERMINATED))
        with torch.no_grad():
            a_next, bonus = self.next_action(x_next)
            q1, q2, q_c_next = self.q_values((*Q_REWARD, Q_COST), x_next, a_next, target=True)
            y = td_target(mb.get((keys.NEXT, keys.REWARD)), term, cfg.gamma, torch.min(q1, q2) + bonus)
            y_c = td_target(mb.get((keys.NEXT, keys.COST)), term, cfg.cost_gamma, q_c_next)
        q1, q2, q_c = self.q_values((*Q_REWARD, Q_COST), x, self.scaled(mb.get(keys.ACTION)))
        loss_q = (q1 - y).pow(2).mean() + (q2 - y).pow(2).mean()
        loss_qc = (q_c - y_c).pow(2).mean()
        return loss_q + loss_qc, {
            "loss_q": loss_q.detach(),
            "loss_qc": loss_qc.detach(),
            "q_reward": q1.mean().detach(),
        }

    def penalised_q(
        self, x: torch.Tensor, action: torch.Tensor, reward_critics: tuple[str, ...] = Q_REWARD
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(min_j Q_j(s, a) - sum_k lambda_k Q_c,k(s, a), Q_c(s, a))`` on features ``x`` and a
        scaled action: what the actor ascends (the Lagrangian of Ha et al. 2020), and the cost
        estimate the multiplier reads."""
        if not any(self.lambdas):
            # lambda = 0: Q_c adds nothing to the actor's gradient; read without a graph, it spares its backward.
            q_r = self.q_values(reward_critics, x, action)
            with torch.no_grad():
                (q_c,) = self.q_values((Q_COST,), x, action)
            return (q_r[0] if len(q_r) == 1 else torch.min(*q_r)), q_c
        *q_r, q_c = self.q_values((*reward_critics, Q_COST), x, action)
        q_r = q_r[0] if len(q_r) == 1 else torch.min(*q_r)
        return q_r - (q_c * torch.tensor(self.lambdas, device=x.device)).sum(-1, keepdim=True), q_c

    # --- what an algorithm provides -------------------------------------------------------------
    def policy_action(self, x: torch.Tensor) -> torch.Tensor:
        """The current policy's action on features ``x``, in [-1, 1] units (a sample, or the deterministic one)."""
        raise NotImplementedError

    def next_action(self, x_next: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The TD target's next action in [-1, 1] units, and the bonus added to ``min Q'`` (SAC: ``-alpha log pi``)."""
        raise NotImplementedError

    def actor_step(self, x: torch.Tensor) -> dict[str, torch.Tensor] | None:
        """One actor (and temperature) step: its statistics, ``q_cost_k`` ``[K]`` among them, or None (delayed)."""
        raise NotImplementedError

    @torch.no_grad()
    def cost_estimate(self) -> torch.Tensor:
        """``[K]`` ``E[Q_c(s, pi(s))]`` over the newest ``cost_window`` transitions' states (module docstring)."""
        x = self.features(self.replay.newest(self.cfg.cost_window).get(keys.OBS))
        (q_c,) = self.q_values((Q_COST,), x, self.policy_action(x))
        return q_c.mean(0)

    # --- the shared update ----------------------------------------------------------------------
    def update(self, batch: TensorDictBase) -> dict[str, float]:
        cfg = self.cfg
        added = self.replay.add(batch)
        if len(self.replay) < max(cfg.warmup_steps, cfg.batch_size):
            return self._stats({}, 0)
        self.steps_due += cfg.utd_ratio * added
        n = int(self.steps_due)
        self.steps_due -= n
        sums: dict[str, torch.Tensor] = {}
        counts: dict[str, int] = {}
        for _ in range(n):
            mb = self.replay.sample()
            x = self.features(mb.get(keys.OBS))
            loss, stats = self.critic_loss(mb, x, self.features(mb.get((keys.NEXT, keys.OBS))))
            self.critic_opt.zero_grad(set_to_none=True)
            loss.backward()
            self.critic_opt.step()
            self.gradient_steps += 1
            actor = self.actor_step(x)
            if actor is not None:
                stats.update(actor)
                self.targets.soft_update(cfg.tau)  # every step for SAC; delayed with the actor for TD3
            for k, v in stats.items():
                sums[k] = sums[k] + v if k in sums else v
                counts[k] = counts.get(k, 0) + 1
        means = {k: v / counts[k] for k, v in sums.items()}
        q_cost = means.pop("q_cost_k", None)  # over the replayed states
        if q_cost is not None and self.multiplier is not None:
            if self.cfg.cost_window:
                q_cost = self.cost_estimate()  # over the current policy's own states
            self.multiplier.update(q_cost.tolist())  # once per iteration, as ppo_lag's lambda
        out = {k: v.item() for k, v in means.items()}
        out["q_cost"] = q_cost.mean().item() if q_cost is not None else float("nan")
        check_finite(**{k: v for k, v in out.items() if not math.isnan(v)})
        check_parameters_finite(self.agent)
        return self._stats(out, n)

    def _stats(self, out: dict[str, float], steps: int) -> dict[str, float]:
        row = {k: out.get(k, float("nan")) for k in self.stats}
        row.update(gradient_steps=steps, buffer_size=len(self.replay))
        row["lagrange_multiplier"] = logged_multiplier(self.lambdas)
        return row

    # --- checkpointing: networks, targets, optimizers, multiplier and the buffer -----------------
    def state_dict(self) -> dict:
        return {
            "networks": self.agent.state_dict(),
            "targets": self.targets.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "multiplier": {} if self.multiplier is None else self.multiplier.state_dict(),
            "replay": self.replay.state_dict(),
            "steps_due": self.steps_due,
            "gradient_steps": self.gradient_steps,
        }

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["networks"])
        self.targets.load_state_dict(state["targets"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        if self.multiplier is not None:
            self.multiplier.load_state_dict(state["multiplier"])
        if "replay" in state:
            self.replay.load_state_dict(state["replay"])
        self.steps_due, self.gradient_steps = float(state["steps_due"]), int(state["gradient_steps"])


__all__ = ["LagrangeFields", "OffPolicy", "OffPolicyConfig", "TargetCritics", "discounted_budget", "td_target"]
