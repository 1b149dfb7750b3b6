"""env=safety_gym: Safety-Gymnasium 1.0.0's own tasks on our stack.

The package is installed by ``make setup-safety-gym`` (a prerequisite of ``make test``). Building a
navigation task's world (an MJCF compile, at every reset) takes about 0.5 s, so these tests build as
few as they can: a sample of the offered tasks covering every robot, task family, level and velocity
task, and one ppo_lag run on SafetyPointGoal1-v0 shared by the training, resume, evaluation and
video tests. ``SAFETY_GYM_ALL_TASKS=1`` checks every offered task (77, a few minutes) and the saved
state of envs in worker processes (``env.vector=async``).
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

from helpers.policies import ForwardPolicy  # noqa: E402
from helpers.runs import eval_result, metrics_rows  # noqa: E402

from cmdp_rl import Collector, finished_episodes, keys, make_env, train  # noqa: E402
from cmdp_rl.config.run_config import ConfigError, compose_config  # noqa: E402
from cmdp_rl.envs.safety_gym.compat import import_safety_gymnasium  # noqa: E402
from cmdp_rl.envs.safety_gym.env import SafetyGymEnvConfig, make_task  # noqa: E402
from cmdp_rl.envs.safety_gym.tasks import TASKS, task_problem  # noqa: E402
from cmdp_rl.run.checkpoint import load_checkpoint  # noqa: E402
from cmdp_rl.run.resume import resume_config  # noqa: E402

FULL = bool(os.environ.get("SAFETY_GYM_ALL_TASKS"))
# Every robot (Point: the training run below), family, level; every velocity task.
SAMPLE = [
    "SafetyCarButton1-v0",
    "SafetyRacecarPush0-v0",
    "SafetyDoggoCircle1-v0",
    "SafetyAntGoal2-v0",
    "SafetyPointRun0-v0",
    *[t for t in TASKS if "Velocity" in t],
]
CHECKED = sorted(TASKS) if FULL else SAMPLE


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


def test_the_six_value_step_reaches_the_batch():
    """Observations, rewards and costs of Safety-Gymnasium's own six-value step (the package's env,
    no adapter) arrive in the collector's batch unchanged; the time limit as truncation."""
    task, action = "SafetyPointCircle1-v0", np.array([1.0, 0.0])  # out of the circle's boundaries: cost from step 59
    env = make_env(SafetyGymEnvConfig(task=task, num_envs=2, max_steps=100))
    forward = ForwardPolicy(lambda obs: torch.tensor([[1.0, 0.0]]).expand(obs.shape[0], 2))
    batch = Collector(env, forward, rollout_steps=100, seed=0).collect()
    env.close()
    obs, reward, cost = [], [], []
    for i in range(2):  # gymnasium seeds env i with seed + i
        theirs = package_env(task)
        steps = [theirs.reset(seed=i)[0]] + [theirs.step(action.copy()) for _ in range(100)]
        obs.append(np.stack([steps[0], *(s[0] for s in steps[1:-1])]))
        reward.append([s[1] for s in steps[1:]])
        cost.append([s[2] for s in steps[1:]])
        assert not any(s[3] or s[4] for s in steps[1:])  # the package's own limit is 500 steps
        theirs.close()
    assert np.array_equal(batch[keys.OBS].numpy(), np.asarray(obs, np.float32))
    assert batch[keys.NEXT][keys.REWARD][..., 0].tolist() == np.float32(reward).tolist()
    assert batch[keys.NEXT][keys.COST][..., 0].tolist() == cost and np.sum(cost) > 0
    truncated = batch[keys.NEXT][keys.TRUNCATED][..., 0]
    assert truncated[:, 99].all() and truncated.sum() == 2 and not batch[keys.NEXT][keys.TERMINATED].any()
    eps = finished_episodes(batch)
    assert eps["cost"].tolist() == [[sum(c)] for c in cost] and eps["length"].tolist() == [100.0, 100.0]


def test_a_velocity_task_steps_as_the_package_does():
    ours, theirs = make_task("SafetyHalfCheetahVelocity-v1"), package_env("SafetyHalfCheetahVelocity-v1")
    assert np.array_equal(ours.reset(seed=3)[0], theirs.reset(seed=3)[0])
    rng = np.random.default_rng(1)
    for _ in range(120):
        a = rng.uniform(-1, 1, ours.action_space.shape).astype(ours.action_space.dtype)
        o1, r1, term1, trunc1, info = ours.step(a)
        o2, r2, c2, term2, trunc2, _ = theirs.step(a.copy())
        assert np.array_equal(o1, o2) and r1 == r2 and info["cost"] == c2 and (term1, trunc1) == (term2, trunc2)


def test_a_velocity_task_saved_state_continues_bit_for_bit():
    """(A navigation task's saved state: the resumed training run below, which restores its world.)"""
    a = make_task("SafetyAntVelocity-v1")
    a.reset(seed=2)
    actions = np.random.default_rng(0).uniform(-1, 1, (60, *a.action_space.shape)).astype(a.action_space.dtype)
    for act in actions[:30]:
        a.step(act)
    b = make_task("SafetyAntVelocity-v1")
    b.load_state_dict(pickle.loads(pickle.dumps(a.state_dict())))
    for act in actions[30:]:
        s1, s2 = a.step(act), b.step(act)
        assert np.array_equal(s1[0], s2[0]) and s1[1:4] == s2[1:4] and s1[4]["cost"] == s2[4]["cost"]


@pytest.mark.skipif(not FULL, reason="worker processes rebuild every world (~15 s): SAFETY_GYM_ALL_TASKS=1")
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
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "safety_gymnasium" else real(name, *a)
    )
    with pytest.raises(ConfigError, match="make setup-safety-gym"):
        compose_config(["env=safety_gym"])


def test_unsupported_task_is_refused_in_one_line():
    with pytest.raises(ConfigError) as refused:
        compose_config(["env=safety_gym", "env.task=SafetyPointGoal1Vision-v0"])
    assert str(refused.value) == (
        "env.task must be an offered Safety-Gymnasium task, got 'SafetyPointGoal1Vision-v0': "
        "it observes camera images (our policies take flat vectors); use SafetyPointGoal1-v0"
    )


# One short ppo_lag run on SafetyPointGoal1-v0: 2 iterations of 64 steps on one env, whose first
# episode spans the checkpoint after iteration 1 (so a resume restores a world mid-episode). Episodes
# of 150 steps: none ends in the contract check's 100 steps or in training, each end costing a reset
# (a world rebuild).
RUN = [
    "env=safety_gym",
    "env.task=SafetyPointGoal1-v0",
    "algo=ppo_lag",
    "env.num_envs=1",
    "env.max_steps=150",
    "rollout_steps=64",
    "total_steps=128",
    "checkpoint_every=1",
    "eval_episodes=1",
]


def _evaluate_cli():
    from cmdp_rl.cli import evaluate as module

    return module


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("safety_gym") / "run"
    result = train(compose_config(RUN), out, echo=lambda _: None)
    return out, result


def test_a_short_ppo_lag_run_writes_its_outputs(run):
    out, result = run
    assert {"config.yaml", "metrics.csv", "eval.json", "checkpoint.pt", "run_info.json"} <= {
        p.name for p in out.iterdir()
    }
    assert [row["iteration"] for row in metrics_rows(out)] == ["1", "2"]
    assert result["cost_limit"] == 25.0 and result["episodes"] == 1 and result["episode_length"] == 150.0
    assert 0.0 <= result["episode_cost"] <= 150.0 and eval_result(out)["episode_length"] == 150.0
    assert load_checkpoint(out / "checkpoint.pt")["iteration"] == 2


def test_a_resumed_run_ends_as_the_uninterrupted_one(run, tmp_path):
    whole, _ = run
    short = tmp_path / "short"
    cfg = compose_config([*RUN, "total_steps=64"])
    train(cfg, short, echo=lambda _: None)
    # as `train.py resume=<short> total_steps=128` does
    train(resume_config(short, {"total_steps": 128}, ["total_steps"]), echo=lambda _: None)
    assert metrics_rows(short) == metrics_rows(whole)  # every column but wall-clock, bit for bit
    assert eval_result(short) == eval_result(whole)
    a, b = (load_checkpoint(d / "checkpoint.pt")["members"][0]["algo_state"] for d in (whole, short))
    assert all(torch.equal(t, b["networks"][k]) for k, t in a["networks"].items())


def test_evaluate_a_navigation_run(run, capsys):
    out, _ = run
    assert _evaluate_cli().main([f"run={out}", "episodes=1"]) == 0
    printed = capsys.readouterr().out
    assert "episode_cost" in printed and "episode_length  150.0" in printed


def _headless_gl_problem() -> str | None:
    """Why MuJoCo cannot render offscreen here (None if it can): gymnasium's offscreen viewer (the
    one the tasks use, reading MUJOCO_GL as video.py sets it) on an empty model, no world to build."""
    import mujoco
    from gymnasium.envs.mujoco.mujoco_rendering import OffScreenViewer

    from cmdp_rl.report.video import HEADLESS_GL, _headless_gl

    _headless_gl()
    model = mujoco.MjModel.from_xml_string("<mujoco/>")
    try:
        OffScreenViewer(model, mujoco.MjData(model), 16, 16).close()
    except Exception as exc:  # noqa: BLE001 - OpenGL's failures come as many types
        return f"{(str(exc).strip().splitlines() or [type(exc).__name__])[0]}; {HEADLESS_GL}"
    return None


def test_video_of_a_navigation_run_renders_headless(run, tmp_path):
    pytest.importorskip("moviepy")
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    problem = _headless_gl_problem()
    if problem:
        pytest.skip(f"no headless OpenGL (MUJOCO_GL={os.environ.get('MUJOCO_GL')}): {problem}")
    out, _ = run
    assert (
        _evaluate_cli().main([f"run={out}", "video=true", "video_steps=8", "episodes=1", f"video_dir={tmp_path / 'v'}"])
        == 0
    )
    from moviepy import VideoFileClip

    video = tmp_path / "v" / "policy-episode-0.mp4"
    assert imageio_ffmpeg.count_frames_and_secs(str(video))[0] == 9  # the reset frame and one per step
    clip = VideoFileClip(str(video))
    assert clip.size == [320, 240] and clip.fps == 32  # render_fps 30, as a power of two (video.exact_fps)
    first, last = np.asarray(clip.get_frame(0)), np.asarray(clip.get_frame(8 / 32))
    assert first.std() > 10 and not np.array_equal(first, last)  # a scene, and the robot moves in it
    clip.close()


def test_the_contract_check_of_an_async_run_steps_its_probe_in_this_process():
    # An async run's envs live in worker processes, where the check cannot read their raw info; its
    # separate probe envs run in this process instead (this was a TypeError before training).
    from cmdp_rl.run.start import check_env_contract

    cfg = compose_config(["env=safety_gym", "env.task=SafetyPointGoal1-v0", "env.vector=async", "env.num_envs=2"])
    check_env_contract(cfg)  # raises on a breach or an unsupported env
