"""Policy heads: ``policy=mlp`` (memoryless), ``lstm``/``gru`` (recurrent state,
policies/recurrent.py) or ``transformer`` (a window of the last K steps, policies/transformer.py).
Each builds an :class:`~cmdp_rl.policies.agent.Agent`: an actor and critics keyed by signal,
differing from one head to another only in their networks (``Body``)."""

from __future__ import annotations

from cmdp_rl.policies.agent import Actor, Agent, Body, Critic, make_agent

__all__ = ["Actor", "Agent", "Body", "Critic", "make_agent"]
