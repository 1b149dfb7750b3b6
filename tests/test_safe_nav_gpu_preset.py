"""The many-worlds preset (configs/experiment/safe_nav_gpu.yaml, issue 53) trains on the CPU at small scale: the same
shape (short rollouts per world, few large minibatches) with MuJoCo's C engine, so that a GPU's minutes go to measuring."""

import importlib.util
import math

import pytest

if importlib.util.find_spec("safety_gymnasium") is None:
    pytest.skip("Safety-Gymnasium is installed by `make setup-safety-gym`", allow_module_level=True)

from helpers.runs import eval_result, metrics_rows  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402

from cmdp_rl import train  # noqa: E402
from cmdp_rl.config.run_config import CONFIG_DIR, compose_config  # noqa: E402

SMALL = ["env.physics=mujoco", "device=cpu", "env.num_envs=256", "env.max_steps=64", "eval_episodes=4"]


def test_the_preset_is_massively_parallel_ppo_lag_on_point_goal1():
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):  # as composed, before the
        cfg = compose("config", overrides=["+experiment=safe_nav_gpu"])  # device check a CPU-only machine makes
    assert (cfg.algo.name, cfg.env.task, cfg.env.physics, cfg.device) == ("ppo_lag", "PointGoal1", "mjwarp", "cuda")
    assert cfg.env.num_envs * cfg.rollout_steps >= 100_000  # batches of over 1e5 steps at the GPU's scale
    assert (cfg.algo.num_minibatches, cfg.algo.update_epochs) == (4, 5)


def test_the_preset_trains_on_the_cpu_with_a_few_hundred_worlds(tmp_path, quiet):
    cfg = compose_config(["+experiment=safe_nav_gpu", *SMALL, "total_steps=32768"])
    assert cfg.rollout_steps * cfg.env.num_envs == 8192
    train(cfg, tmp_path, echo=quiet)
    rows = metrics_rows(tmp_path)
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3, 4]
    ended = [r for r in rows if int(r["episodes"]) > 0]
    assert ended and all(int(r["episodes"]) == 256 for r in ended)  # every world's 64-step episode, each counted once
    assert all(math.isfinite(float(r["loss_pi"])) and math.isfinite(float(r["loss_vc"])) for r in rows)
    result = eval_result(tmp_path)
    assert result["episodes"] == 4 and set(result["modes"]) == {"mean_action", "sampled"}
