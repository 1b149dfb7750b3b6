"""env=safety_gym: Safety-Gymnasium 1.0.0's own tasks on our stack.

The package is installed by ``make setup-safety-gym`` (a prerequisite of ``make test``). Every
offered task is checked with ``SAFETY_GYM_ALL_TASKS=1`` (77 tasks, a few minutes); by default a
sample covering every robot, every task family, every level and every velocity task.
"""

import importlib.util
import os
import pickle

import numpy as np
import pytest
import torch

# Not importorskip: the package imports only through our compatibility layer.
if importlib.util.find_spec("safety_gymnasium") is None:
    pytest.skip("Safety-Gymnasium is installed by `make setup-safety-gym`", allow_module_level=True)

from cmdp_rl import Collector, finished_episodes, keys, make_env, train  # noqa: E402
from cmdp_rl.config import ConfigError, compose_config  # noqa: E402
from cmdp_rl.envs.safety_gym import SafetyGymEnvConfig, make_task  # noqa: E402
from cmdp_rl.envs.safety_gym_compat import import_safety_gymnasium  # noqa: E402
from cmdp_rl.envs.safety_gym_tasks import TASKS, task_problem  # noqa: E402
from conftest import ForwardPolicy, metrics_rows, run_script  # noqa: E402

SAMPLE = ["SafetyPointGoal1-v0", "SafetyCarButton2-v0", "SafetyRacecarPush0-v0", "SafetyDoggoCircle1-v0",
          "SafetyAntGoal2-v0", "SafetyPointRun0-v0", *[t for t in TASKS if "Velocity" in t]]
CHECKED = sorted(TASKS) if os.environ.get("SAFETY_GYM_ALL_TASKS") else SAMPLE


def package_env(task):
    """The task as Safety-Gymnasium builds it (its entry point and kwargs), without our adapter."""
    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    import_safety_gymnasium()
    spec = gym.spec(task)
    return load_env_creator(spec.entry_point)(**spec.kwargs)


def test_offered_tasks_are_registered_with_their_limits_and_the_rest_is_refused_with_a_reason():
    import gymnasium as gym

    import_safety_gymnasium()
    registered = {k: v for k, v in gym.registry.items() if k.startswith("Safety")}
    assert {t: registered[t].max_episode_steps for t in TASKS} == TASKS
    assert len(TASKS) == 5 * 13 + 12
    for task in set(registered) - set(TASKS):
        problem = task_problem(task)
        # every registered id we do not offer is refused for a stated reason, not as unknown
        assert problem and ": it " in problem and "\n" not in problem, task
    assert "use SafetyCarGoal1-v0" in task_problem("SafetyCarGoal1Vision-v0")
    unknown = task_problem("SafetyBlimpGoal1-v0")
    assert unknown.startswith("env.task must be one of Safety{Point,Car,Racecar,Doggo,Ant}")


@pytest.mark.parametrize("task", CHECKED)
def test_offered_task_builds_and_steps_with_a_cost(task):
    env = make_task(task, max_steps=6)
    obs, _ = env.reset(seed=0)
    assert obs.shape == env.observation_space.shape
    rng = np.random.default_rng(0)
    for t in range(6):
        action = rng.uniform(env.action_space.low, env.action_space.high).astype(env.action_space.dtype)
        obs, reward, terminated, truncated, info = env.step(action)
        assert obs.shape == env.observation_space.shape and np.isfinite(obs).all()
        assert isinstance(info["cost"], float) and info["cost"] >= 0.0 and np.isfinite(reward)
        if terminated:  # Ant and Doggo may fall over
            break
    assert terminated or truncated and t == 5  # max_steps=6 truncates the sixth step
    env.close()


@pytest.mark.parametrize("task,action", [
    ("SafetyPointCircle1-v0", [1.0, 0.0]),   # drives out of the circle's boundaries: cost from step 59
    ("SafetyCarGoal1-v0", [1.0, 1.0]),       # into hazards
    ("SafetyHalfCheetahVelocity-v1", None),  # random actions
])
def test_our_step_is_the_package_step(task, action):
    """Observations, rewards, costs and episode ends equal Safety-Gymnasium's six-value step's."""
    ours, theirs = make_task(task), package_env(task)
    o1, _ = ours.reset(seed=3)
    o2, _ = theirs.reset(seed=3)
    assert np.array_equal(o1, o2)
    rng = np.random.default_rng(1)
    costs = []
    for _ in range(120):
        a = np.asarray(action) if action else rng.uniform(-1, 1, ours.action_space.shape)
        a = a.astype(ours.action_space.dtype)
        o1, r1, term1, trunc1, info = ours.step(a)
        o2, r2, c2, term2, trunc2, _ = theirs.step(a.copy())
        assert np.array_equal(o1, o2) and r1 == r2 and info["cost"] == c2
        assert (term1, trunc1) == (term2, trunc2)
        costs.append(c2)
    if action:
        assert sum(costs) > 0  # the comparison covered steps with cost


def test_cost_and_episode_ends_reach_the_batch():
    cfg = SafetyGymEnvConfig(task="SafetyPointCircle1-v0", num_envs=2, max_steps=100)
    env = make_env(cfg)
    forward = ForwardPolicy(lambda obs: torch.tensor([[1.0, 0.0]]).expand(obs.shape[0], 2))
    batch = Collector(env, forward, rollout_steps=110, seed=0).collect()
    # The same two envs stepped by hand: gymnasium seeds env i with seed + i.
    expected = []
    for i in range(2):
        e = make_task("SafetyPointCircle1-v0", max_steps=100)
        e.reset(seed=i)
        expected.append([e.step(np.array([1.0, 0.0]))[4]["cost"] for _ in range(100)])
    cost = batch[keys.NEXT][keys.COST][..., 0]
    assert cost[:, :100].tolist() == expected and sum(map(sum, expected)) > 0
    truncated = batch[keys.NEXT][keys.TRUNCATED][..., 0]
    assert truncated[:, 99].all() and truncated.sum() == 2  # the time limit, as truncation
    eps = finished_episodes(batch)
    assert eps["cost"].tolist() == [[sum(c)] for c in expected] and eps["length"].tolist() == [100.0, 100.0]
    env.close()


@pytest.mark.parametrize("task", ["SafetyCarButton1-v0", "SafetyAntVelocity-v1"])
def test_saved_state_continues_bit_for_bit(task):
    a = make_task(task)
    a.reset(seed=2)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (60, *a.action_space.shape)).astype(a.action_space.dtype)
    for act in actions[:30]:
        a.step(act)
    b = make_task(task)
    b.load_state_dict(pickle.loads(pickle.dumps(a.state_dict())))
    for act in actions[30:]:
        s1, s2 = a.step(act), b.step(act)
        assert np.array_equal(s1[0], s2[0]) and s1[1:4] == s2[1:4] and s1[4]["cost"] == s2[4]["cost"]


def test_async_vector_env_steps_as_sync_and_saves_its_state():
    cfgs = [SafetyGymEnvConfig(task="SafetyPointGoal1-v0", num_envs=2, vector=v) for v in ("sync", "async")]
    sync, asyn = make_env(cfgs[0]), make_env(cfgs[1])
    try:
        assert torch.equal(sync.reset(seed=4), asyn.reset(seed=4))
        gen = torch.Generator().manual_seed(0)
        actions = [torch.rand(2, 2, generator=gen) * 2 - 1 for _ in range(20)]
        for act in actions[:10]:
            s, a = sync.step(act), asyn.step(act)
            assert all(torch.equal(x, y) for x, y in zip(s, a))
        # state out of the worker processes, into the in-process envs, and back into the workers
        sync.load_state_dict(pickle.loads(pickle.dumps(asyn.state_dict())))
        asyn.load_state_dict(sync.state_dict())
        for act in actions[10:]:
            s, a = sync.step(act), asyn.step(act)
            assert all(torch.equal(x, y) for x, y in zip(s, a))
    finally:
        sync.close()
        asyn.close()


def test_config_defaults_and_checks():
    cfg = compose_config(["env=safety_gym"])
    assert cfg.env.task == "SafetyPointGoal1-v0" and cfg.normalize.obs
    for algo in ("ppo", "ppo_lag", "pid_lag", "cpo", "penalty"):  # d = 25 for every algorithm here
        assert compose_config(["env=safety_gym", f"algo={algo}"]).algo.cost_limit == 25.0
    assert compose_config(["env=reach1d", "algo=ppo_lag"]).algo.cost_limit == 1.0
    assert compose_config(["env=safety_gym", "algo.cost_limit=5"]).algo.cost_limit == 5.0
    with pytest.raises(ConfigError, match=r"env.max_steps must be in \[0, 500\] for SafetyPointCircle2-v0"):
        compose_config(["env=safety_gym", "env.task=SafetyPointCircle2-v0", "env.max_steps=501"])


def test_missing_package_is_a_one_line_config_error(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "safety_gymnasium" else real(name, *a))
    with pytest.raises(ConfigError, match="make setup-safety-gym"):
        compose_config(["env=safety_gym"])


def test_unsupported_task_is_refused_in_one_line(tmp_path):
    proc = run_script("train.py", "env=safety_gym", "env.task=SafetyPointGoal1Vision-v0", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines == ["config error: env.task must be an offered Safety-Gymnasium task, got "
                     "'SafetyPointGoal1Vision-v0': it observes camera images (our policies take flat vectors); "
                     "use SafetyPointGoal1-v0"]


def test_a_short_training_run_in_process(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = compose_config(["env=safety_gym", "env.task=SafetyCarGoal1-v0", "env.num_envs=2", "env.max_steps=100",
                          "rollout_steps=64", "total_steps=256", "eval_episodes=1", "algo=cpo"])
    result = train(cfg, tmp_path / "run", echo=lambda _: None)
    assert result["episodes"] == 1 and result["episode_length"] == 100.0 and result["cost_limit"] == 25.0
    assert 0.0 <= result["episode_cost"] <= 100.0
    assert len(metrics_rows(tmp_path / "run")) == 2  # two iterations


def test_train_resume_and_evaluate_from_the_command_line(tmp_path):
    """ppo_lag on SafetyPointGoal1-v0 through train.py, resumed, evaluated (that a resumed run
    continues exactly rests on the env's saved state: test_saved_state_continues_bit_for_bit)."""
    run_dir = tmp_path / "run"
    first = run_script("train.py", "env=safety_gym", "env.task=SafetyPointGoal1-v0", "env.num_envs=2",
                       "env.max_steps=100", "rollout_steps=64", "eval_episodes=1", "checkpoint_every=1",
                       "algo=ppo_lag", "total_steps=128", f"hydra.run.dir={run_dir}")
    assert first.returncode == 0, first.stderr
    assert "training ppo_lag on safety_gym" in first.stdout and "cost limit 25.0" in first.stdout
    resumed = run_script("train.py", f"resume={run_dir}", "total_steps=256")
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming" in resumed.stdout and "warning" not in resumed.stdout
    assert [row["iteration"] for row in metrics_rows(run_dir)] == ["1", "2"]
    ev = run_script("evaluate.py", f"run={run_dir}", "episodes=1")
    assert ev.returncode == 0, ev.stderr
    assert "episode_cost" in ev.stdout and "episode_length  100.0" in ev.stdout
