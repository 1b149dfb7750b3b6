"""One OmniSafe run for a benchmark campaign (lab/bench/campaign.py), in OmniSafe's own virtual environment.

    <omnisafe venv>/bin/python lab/bench/omnisafe_peer.py ALGO ENV_ID TOTAL_STEPS SEED RUN_DIR

Trains ``ALGO`` (OmniSafe's name: PPOLag, CPO, ...) on ``ENV_ID`` with OmniSafe's own defaults (one env,
its 20,000-step epochs, one torch thread), then runs its final policy on 50 fresh episodes in each mode, the
sampled actions and the mean action, through OmniSafe's evaluator's env and actor (its ``evaluate`` offers the
mean action only), and writes ``peer_result.json`` into ``RUN_DIR``: the per-epoch training curve (OmniSafe's
``Metrics/EpRet`` and ``Metrics/EpCost``, means over its last 50 finished episodes: ``window_length=50`` in
``algorithms/on_policy/base/policy_gradient.py``), the episodes, the config it ran and its timings.

Imports only OmniSafe's stack: this file runs where cmdp_rl is not installed (``../shared/tools/omnisafe/``
builds that environment). OmniSafe cannot resume a run: a killed one starts again.
"""

from __future__ import annotations

import glob
import json
import os
import sys
import time
import warnings

EPISODES = 50  # evaluation episodes per mode, as the campaign's cmdp_rl runs
EVAL_SEED = 1_000_003  # plus the run's seed: the evaluation layouts are never the training ones


def train(algo: str, env_id: str, total_steps: int, seed: int, run_dir: str) -> tuple[str, float]:
    """Train with OmniSafe's defaults into ``run_dir/omnisafe``; returns its log directory and the seconds."""
    import omnisafe

    cfgs = {
        "seed": seed,
        "train_cfgs": {
            "device": "cpu",
            "torch_threads": 1,
            "vector_env_nums": 1,
            "parallel": 1,
            "total_steps": total_steps,
        },
        "logger_cfgs": {"use_wandb": False, "use_tensorboard": False, "log_dir": os.path.join(run_dir, "omnisafe")},
    }
    agent = omnisafe.Agent(algo, env_id, custom_cfgs=cfgs)
    start = time.perf_counter()
    agent.learn()
    return agent.agent.logger.log_dir, time.perf_counter() - start


def progress_rows(log_dir: str) -> list[dict[str, float]]:
    import pandas as pd

    df = pd.read_csv(os.path.join(log_dir, "progress.csv"))
    return [
        {
            "step": int(r["TotalEnvSteps"]),
            "episode_return": float(r["Metrics/EpRet"]),
            "episode_cost": float(r["Metrics/EpCost"]),
        }
        for _, r in df.iterrows()
    ]


def evaluate(log_dir: str, seed: int) -> dict[str, dict[str, list[float]]]:
    """The last saved policy's whole episodes, sampled and mean action, on the evaluator's env."""
    import torch
    from omnisafe import Evaluator

    saved = sorted(
        glob.glob(os.path.join(log_dir, "torch_save", "epoch-*.pt")), key=lambda p: int(p.split("-")[-1][:-3])
    )
    out = {}
    for name, deterministic in (("sampled", False), ("mean_action", True)):
        evaluator = Evaluator()
        evaluator.load_saved(save_dir=log_dir, model_name=os.path.basename(saved[-1]))
        env, actor = evaluator._env, evaluator._actor  # its evaluate() hard-codes the mean action
        torch.manual_seed(seed + EVAL_SEED)
        returns, costs = [], []
        for episode in range(EPISODES):
            obs, _ = env.reset(seed=seed + EVAL_SEED + episode)
            ret = cost = 0.0
            done = False
            while not done:
                with torch.no_grad():
                    act = actor.predict(obs, deterministic=deterministic)
                obs, rew, c, terminated, truncated, _ = env.step(act)
                ret, cost = ret + float(rew), cost + float(c)
                done = bool(terminated or truncated)
            returns.append(ret)
            costs.append(cost)
        out[name] = {"returns": returns, "costs": costs}
    return out


def main(argv: list[str]) -> int:
    warnings.filterwarnings("ignore")
    algo, env_id, total_steps, seed, run_dir = argv[0], argv[1], int(argv[2]), int(argv[3]), argv[4]
    os.makedirs(run_dir, exist_ok=True)
    log_dir, learn_s = train(algo, env_id, total_steps, seed, run_dir)
    result = {
        "algo": algo,
        "env_id": env_id,
        "total_steps": total_steps,
        "seed": seed,
        "learn_s": learn_s,
        "progress": progress_rows(log_dir),
        "evaluation": evaluate(log_dir, seed),
        "config": json.load(open(os.path.join(log_dir, "config.json"))),
    }
    tmp = os.path.join(run_dir, "peer_result.json.tmp")
    with open(tmp, "w") as f:
        json.dump(result, f)
    os.replace(tmp, os.path.join(run_dir, "peer_result.json"))
    print(f"omnisafe {algo} {env_id} seed {seed}: {total_steps} steps in {learn_s:.0f} s; {run_dir}/peer_result.json")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
