"""The tiny run every lifecycle test trains (seconds), its command line, and ways to read its outputs."""

import copy
import csv
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WALL_CLOCK = ("sps", "time_s")  # the only columns allowed to differ between identical runs

# 2 envs x 16 steps per iteration, random starts (the envs' generators matter), short episodes
# (several end per iteration), wall=pass with a small budget (lambda moves every iteration). The
# multiplier's options are pinned, so that a changed default moves only the tests about it; a test of
# another algorithm drops the node or replaces it whole.
MULTIPLIER = {"kind": "dual", "lr": 0.5, "init": 0.0, "scale": "budget"}
TINY = {
    "env": {"num_envs": 2, "max_steps": 12, "wall": "pass", "start": [0.3, 0.48]},
    "algo": {"name": "ppo_lag", "update_epochs": 2, "num_minibatches": 2, "cost_limit": 0.2, "multiplier": MULTIPLIER},
    "rollout_steps": 16,
    "total_steps": 7 * 32,
    "checkpoint_every": 2,
    "eval_episodes": 4,
    # Pinned whole, so that a changed default moves only the tests about it. ppo_lag deploys a valued mixture
    # (deploy.policy=auto), kept tiny: 8 episodes per snapshot.
    "deploy": {"policy": "auto", "window": 0.5, "snapshots": 16, "weights": "feasible", "episodes": 8, "margin": 3.0},
    "log_interval": 1,
}


def tiny(**overrides) -> dict:
    """The TINY config with top-level overrides and ``algo``/``env`` entries merged in."""
    cfg = copy.deepcopy(TINY)
    for k, v in overrides.items():
        if isinstance(v, dict) and k in cfg:
            cfg[k].update(v)
        else:
            cfg[k] = v
    return cfg


def cli_args(cfg: dict) -> list[str]:
    """Hydra command-line overrides for a config dict like TINY (a nested node, as algo.multiplier,
    one override per field)."""
    out = []
    for k, v in cfg.items():
        if isinstance(v, dict):
            for kk, vv in v.items():
                if k == "algo" and kk == "name":
                    out.insert(0, f"algo={vv}")
                elif isinstance(vv, dict):  # a node; its kind (the multiplier's) is a group choice
                    out += [f"{k}/{kk}={vv['kind']}"] if "kind" in vv else []
                    out += [
                        f"{k}.{kk}.{f}={json.dumps(x) if not isinstance(x, str) else x}"
                        for f, x in vv.items()
                        if f != "kind"
                    ]
                else:
                    out.append(f"{k}.{kk}={json.dumps(vv)}")
        else:
            out.append(f"{k}={json.dumps(v) if not isinstance(v, str) else v}")
    return out


def run_script(script: str, *args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(ROOT / script), *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


def metrics_rows(run_dir: Path, drop=WALL_CLOCK) -> list[dict]:
    with open(Path(run_dir) / "metrics.csv") as f:
        return [{k: v for k, v in row.items() if k not in drop} for row in csv.DictReader(f)]


def tail_means(run_dir: Path, *columns: str, last: int = 10) -> tuple[float, ...]:
    """Each column's mean over the run's last ``last`` iterations (metrics.csv): a learning test's
    reading of where training ended, less noisy than the final row alone."""
    with open(Path(run_dir) / "metrics.csv") as f:
        rows = list(csv.DictReader(f))[-last:]
    return tuple(sum(float(r[c]) for r in rows) / len(rows) for c in columns)


def eval_result(run_dir: Path) -> dict:
    out = json.loads((Path(run_dir) / "eval.json").read_text())
    out.pop("train_time_s")
    return out


# A uniform random policy on Reach1D with the passable wall: return 0.556, cost 3.54 per episode (8192 episodes,
# measured). A learning test's policy that reaches the goal earns well above it (test_trpo_lag, test_pcpo).
RANDOM_RETURN = 0.556
