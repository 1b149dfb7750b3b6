"""Policy heads (``policy=mlp|lstm|gru|transformer``), each building an :class:`~cmdp_rl.policies.agent.Agent`."""

from __future__ import annotations

from cmdp_rl.policies.agent import Actor, Agent, Body, Critic, make_agent

__all__ = ["Actor", "Agent", "Body", "Critic", "make_agent"]
