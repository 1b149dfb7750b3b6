"""The throughput table's measurements (:mod:`lab.bench.benchmark_throughput` runs them and prints the
table): env, rollout and training steps per second, and peak memory, for one setting."""

from __future__ import annotations

import re
import resource
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

import cmdp_rl  # noqa: E402
from cmdp_rl import Collector, load_config, make_agent, make_env  # noqa: E402
from cmdp_rl.config.run_config import compose_config  # noqa: E402
from cmdp_rl.envs import Reach1D  # noqa: E402
from cmdp_rl.envs.reach1d.task import Reach1DConfig  # noqa: E402
from cmdp_rl.policies.mlp import PolicyConfig  # noqa: E402

MEMORY_HEADS = ("lstm", "transformer")  # history-dependent heads, benchmarked at N = 1024


# --- memory ------------------------------------------------------------------------------------
def _reset_peak(device: str) -> None:
    """Restart the peak-RSS counter (Linux: writing 5 to clear_refs resets VmHWM), and CUDA's."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass  # the peak then covers the whole process so far
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()


def _peak(device: str) -> dict[str, float]:
    try:
        rss_kb = int(re.search(r"VmHWM:\s+(\d+)", Path("/proc/self/status").read_text()).group(1))
    except (OSError, AttributeError):
        rss_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out = {"peak_rss_mb": rss_kb / 1024}
    if device == "cuda":
        out["cuda_max_allocated_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return out


def _sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


CPU_SHARE: list[float] = []  # this process's CPU time / wall time of each measurement


def _rate(run: Callable[[], int], seconds: float, device: str) -> float:
    """Steps per second of ``run`` (which returns the steps it made), after one warm-up call."""
    run()
    _sync(device)
    steps, start, cpu = 0, time.perf_counter(), time.process_time()
    while True:
        steps += run()
        _sync(device)
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            CPU_SHARE.append((time.process_time() - cpu) / elapsed)
            return steps / elapsed


# --- the measurements --------------------------------------------------------------------------
@dataclass
class Setting:
    backend: str
    num_envs: int
    rollout_steps: int  # as in training: the collector's steps per env per call
    train_overrides: list[str] = field(default_factory=list)
    label: str = ""

    def __post_init__(self) -> None:
        self.label = self.label or f"{self.backend} N={self.num_envs}"


def env_rate(s: Setting, seconds: float, device: str) -> float:
    rng = np.random.default_rng(0)
    if s.backend == "gym" and s.num_envs == 1:
        env = Reach1D()  # gymnasium's API, no vector wrapper
        env.reset(seed=0)
        actions = rng.uniform(-0.1, 0.1, size=(1000, 1)).astype(np.float32)

        def run() -> int:
            for a in actions:
                _, _, term, trunc, _ = env.step(a)
                if term or trunc:
                    env.reset()
            return len(actions)

        return _rate(run, seconds, device)
    venv = make_env(Reach1DConfig(backend=s.backend, num_envs=s.num_envs), device=device)
    venv.reset(seed=0)
    if s.backend == "gym":
        raw = venv.envs  # gymnasium's SyncVectorEnv itself, SAME_STEP autoreset
        acts = list(rng.uniform(-0.1, 0.1, size=(100, s.num_envs, 1)).astype(np.float32))

        def run() -> int:
            for a in acts:
                raw.step(a)
            return len(acts) * s.num_envs
    else:
        acts = list(torch.rand(20, s.num_envs, 1, device=device) * 0.2 - 0.1)

        def run() -> int:
            for a in acts:
                venv.step(a)
            return len(acts) * s.num_envs

    try:
        return _rate(run, seconds, device)
    finally:
        venv.close()


def rollout_rate(s: Setting, rollout_steps: int, seconds: float, device: str) -> float:
    cfg = load_config({"env": {"backend": s.backend, "num_envs": s.num_envs}, "device": device})
    env = make_env(cfg.env, device=device)
    # The policy the setting trains (a preset's tuning may set its width): train/rollout compares
    # the same network.
    agent = make_agent(compose_config(["algo=ppo_lag", *s.train_overrides]).policy, env)
    collector = Collector(env, agent, rollout_steps, seed=0)
    try:
        return _rate(lambda: (collector.collect(), rollout_steps * s.num_envs)[1], seconds, device)
    finally:
        env.close()


def plain_loop_rate(num_envs: int, rollout_steps: int, seconds: float) -> float:
    """The yardstick for the collector: a hand-written loop over the same SyncVectorEnv with the
    same MLP network, sampling a Gaussian and keeping what a batch needs (obs, action, log-prob,
    reward, cost, flags), with none of the collector's generality."""
    cfg = load_config({"env": {"num_envs": num_envs}})
    env = make_env(cfg.env)
    actor = make_agent(cfg.policy, env).actor
    head = lambda o: tuple(actor.head(o).values())  # noqa: E731 - the GaussianHead: (loc, scale)
    raw = env.envs
    state = {"obs": raw.reset(seed=0)[0]}
    zeros = np.zeros(num_envs)

    @torch.no_grad()
    def run() -> int:
        rows = []
        obs = state["obs"]
        for _ in range(rollout_steps):
            o = torch.from_numpy(obs)
            loc, scale = head(o)
            a = torch.normal(loc, scale)
            logp = torch.distributions.Normal(loc, scale).log_prob(a).sum(-1)
            obs, r, term, trunc, info = raw.step(a.numpy())
            rows.append(
                (
                    o,
                    a,
                    logp,
                    torch.from_numpy(r),
                    torch.from_numpy(np.asarray(info.get("cost", zeros))),
                    torch.from_numpy(term),
                    torch.from_numpy(trunc),
                )
            )
        state["obs"] = obs
        [torch.stack(col) for col in zip(*rows)]
        return rollout_steps * num_envs

    try:
        return _rate(run, seconds, "cpu")
    finally:
        env.close()


def train_rate(overrides: list[str], iterations: int, device: str, threads: int) -> dict[str, Any]:
    """Train ``ppo_lag`` for ``iterations`` on the config ``train.py`` composes for ``overrides``."""
    cfg = compose_config(["algo=ppo_lag", *overrides, f"device={device}", f"threads={threads}"])
    per_iter = cfg.rollout_steps * cfg.env.num_envs
    cfg.total_steps = per_iter * iterations
    cfg.eval_episodes = 1
    cfg.checkpoint_every = 10**9  # one checkpoint, at the end
    with tempfile.TemporaryDirectory() as out:
        start, cpu = time.perf_counter(), time.process_time()
        cmdp_rl.train(cfg, out, echo=lambda line: None)
        CPU_SHARE.append((time.process_time() - cpu) / (time.perf_counter() - start))
        import csv

        rows = list(csv.DictReader(open(Path(out) / "metrics.csv")))
    sps = [float(r["sps"]) for r in rows]
    steady = sps[1:] or sps
    return {
        "train_sps": statistics.median(steady),
        "train_sps_all": sps,
        "iterations": len(sps),
        "batch": per_iter,
        "rollout_steps": cfg.rollout_steps,
        "update_epochs": cfg.algo.update_epochs,
        "num_minibatches": cfg.algo.num_minibatches,
        "policy": cfg.policy.name,
        "net": net_label(cfg.policy),
        "overrides": overrides,
    }


def net_label(policy: PolicyConfig) -> str:
    """The policy's kind and width, e.g. ``mlp 32x32``."""
    if policy.name == "mlp":
        return "mlp " + "x".join(map(str, policy.hidden_sizes))
    return policy.name


def measure(name: str, fn: Callable[[], Any], device: str) -> tuple[Any, dict[str, float]]:
    """``fn()`` and the peak memory and CPU share (CPU time / wall time) it ran with."""
    _reset_peak(device)
    value = fn()
    return value, {**_peak(device), "cpu_share": CPU_SHARE[-1]}
