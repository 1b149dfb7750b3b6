"""evaluate.py video=true: mp4s through gymnasium's RecordVideo, one frame per step plus the reset's.

Reach1D's frame is drawn with numpy (checked pixel by pixel); its video episodes are the replayed
episodes of replay.py (same policy call, same seed); MuJoCo renders headless when it can here; an
env that cannot render, or a missing moviepy, is refused with one line.
"""

import importlib.util

import gymnasium as gym
import numpy as np
import pytest
from helpers.runs import tiny

from cmdp_rl import load_config, train
from cmdp_rl.cli import evaluate as evaluate_cli
from cmdp_rl.config.run_config import ConfigError, compose_config
from cmdp_rl.envs.reach1d.env import FRAME_H, FRAME_W, Reach1D, render_reach1d
from cmdp_rl.envs.reach1d.task import Reach1DConfig
from cmdp_rl.report.reach1d_episodes import record_reach1d
from cmdp_rl.report.video import VideoError, exact_fps, make_render_env, record_video
from cmdp_rl.run.rundir import load_trained

pytest.importorskip("moviepy")  # the test extra installs it (pip install -e '.[test]')
imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")  # moviepy's ffmpeg


def frames_in(path) -> int:
    return imageio_ffmpeg.count_frames_and_secs(str(path))[0]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    train(load_config(tiny(total_steps=64)), out, echo=lambda s: None)
    return out


def test_reach1d_frame_is_drawn_where_the_state_is():
    x, reading, wall, goal = 0.25, 0.6, 0.5, 0.9
    img = render_reach1d(x, reading, collided=False, elapsed=0.5, wall_x=wall, goal=goal)
    assert img.shape == (FRAME_H, FRAME_W, 3) and img.dtype == np.uint8
    scale = FRAME_W - 2 * 16 - 1  # track from pixel 16 (position 0) to 495 (position 1)
    mid = FRAME_H // 2
    assert tuple(img[mid, 16 + round(x * scale)]) == (30, 90, 200)  # the true position: blue disc
    assert tuple(img[mid, 16 + round(wall * scale)]) == (70, 70, 70)  # the wall
    assert tuple(img[mid, 16 + round(goal * scale)]) == (40, 150, 40)  # the goal line
    assert tuple(img[mid - 20, 16 + round(reading * scale)]) == (240, 140, 20)  # the reading's tick
    assert tuple(img[mid - 20, 16 + round(0.3 * scale)]) == (250, 250, 250)  # no tick elsewhere
    assert tuple(img[FRAME_H - 6, 16 + round(0.49 * scale)]) == (150, 150, 150)  # half the time limit...
    assert tuple(img[FRAME_H - 6, 16 + round(0.52 * scale)]) == (250, 250, 250)  # ...and no more
    assert tuple(img[1, 1]) == (250, 250, 250)
    hit = render_reach1d(x, reading, collided=True, elapsed=0.5, wall_x=wall, goal=goal)
    assert tuple(hit[1, 1]) == tuple(hit[-2, FRAME_W // 2]) == (220, 30, 30)  # a collision: red border


def test_rendering_draws_no_random_numbers():
    plain, drawn = Reach1D(), Reach1D(render_mode="rgb_array")
    assert plain.render() is None
    a, _ = plain.reset(seed=3)
    b, _ = drawn.reset(seed=3)
    for _ in range(12):
        drawn.render()
        act = np.array([0.1], np.float32)
        a, b = plain.step(act)[0], drawn.step(act)[0]
        assert np.array_equal(a, b)
    frame = drawn.render()
    # 12 steps of 0.1 from 0.1, blocked at the wall: the disc stays left of it, the crossing tries cost 1
    assert tuple(frame[1, 1]) == (220, 30, 30)
    with pytest.raises(ValueError, match="render_mode"):
        Reach1D(render_mode="human")


def test_reach1d_video_has_a_frame_per_step_and_replays_the_evaluation_episodes(run, tmp_path):
    cfg, env, ac, _, _ = load_trained(run)
    env.close()
    seed = 11
    videos = record_video(ac, cfg.env, tmp_path / "v", episodes=3, deterministic=False, seed=seed)
    replayed = record_reach1d(ac, cfg.env, 3, deterministic=False, seed=seed)
    assert [v.path.name for v in videos] == [f"policy-episode-{i}.mp4" for i in range(3)]
    for v, ep in zip(videos, replayed):
        # the same episodes as replay.py's: same policy call, same seed, same env stream
        assert (v.episode_return, v.episode_cost) == (pytest.approx(ep.episode_return), ep.episode_cost)
        assert v.frames == len(ep.cost) + 1  # the reset frame, then one per step
        assert frames_in(v.path) == v.frames
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == [v.path.name for v in videos]


def test_evaluate_cli_writes_videos_into_the_run(run, capsys):
    assert evaluate_cli.main([f"run={run}", "video=true", "video_episodes=2", "video_steps=10", "episodes=2"]) == 0
    files = sorted((run / "videos").iterdir())
    assert [f.name for f in files] == ["policy-episode-0.mp4", "policy-episode-1.mp4"]
    # cut after 10 steps: the reset frame and 10 more (a count moviepy would cut to 10 at 10 fps)
    assert [frames_in(f) for f in files] == [11, 11]
    out = capsys.readouterr().out
    assert out.count("wrote ") == 2 and "(11 frames" in out


def test_the_torch_backend_renders_through_its_gym_twin():
    env = make_render_env(Reach1DConfig(backend="torch", num_envs=64, stagger=True, obs_noise=0.0, start=0.3))
    assert isinstance(env, Reach1D) and env.start == 0.3 and env.obs_noise == 0.0
    env.close()


def test_velocity_video_renders_headless(tmp_path, monkeypatch):
    pytest.importorskip("mujoco")
    cfg = compose_config(
        [
            "env=velocity",
            "env.num_envs=2",
            "env.max_steps=30",
            "rollout_steps=30",
            "total_steps=60",
            "eval_episodes=2",
            "algo.update_epochs=1",
        ]
    )
    try:
        make_render_env(cfg.env).close()
    except VideoError as exc:  # no EGL here: the error is one line naming what to install
        assert "\n" not in str(exc) and "libegl1" in str(exc)
        pytest.skip(str(exc))
    monkeypatch.chdir(tmp_path)
    train(cfg, tmp_path / "run", echo=lambda _: None)
    assert (
        evaluate_cli.main(
            [f"run={tmp_path / 'run'}", "video=true", "video_steps=8", "episodes=1", f"video_dir={tmp_path / 'v'}"]
        )
        == 0
    )
    video = tmp_path / "v" / "policy-episode-0.mp4"
    assert frames_in(video) == 9
    from moviepy import VideoFileClip

    clip = VideoFileClip(str(video))
    assert clip.size == [320, 240] and clip.fps == 16  # HalfCheetah's render_fps 20, as a power of two
    assert np.asarray(clip.get_frame(0)).std() > 10  # a scene, not a blank frame
    clip.close()


COUNTER_ID = "cmdp_rl_test/VideoCounter-v0"


class Counter(gym.Env):
    """Reports a cost and cannot render."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action):
        return np.zeros(1, np.float32), 0.0, False, False, {"cost": 0.0}


if COUNTER_ID not in gym.registry:
    gym.register(COUNTER_ID, entry_point=Counter, max_episode_steps=5)


def test_an_env_that_cannot_render_is_refused_in_one_line(tmp_path, capsys):
    raw = tiny(total_steps=32)
    raw["env"] = {"name": "gym", "id": COUNTER_ID, "num_envs": 2}
    train(load_config(raw), tmp_path / "run", echo=lambda _: None)
    assert evaluate_cli.main([f"run={tmp_path / 'run'}", "video=true"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: video: env=gym env.id={COUNTER_ID} cannot render rgb_array frames (its render modes: [])"
    assert not (tmp_path / "run" / "videos").exists()

    class Mine:  # a user's env component that declares no render_env
        name = "mine"

    with pytest.raises(ConfigError, match="env=mine cannot render"):
        make_render_env(Mine())


def test_every_frame_count_survives_moviepy_at_a_power_of_two_fps():
    assert [exact_fps(f) for f in (8, 10, 20, 25, 30, 67, 125)] == [8, 8, 16, 32, 32, 64, 128]
    for fps in (8, 16, 32, 64, 128):  # moviepy's count of an n-frame clip is exact for every n
        assert all(int(sum([1.0 / fps] * n) * fps) == n for n in range(1, 1002))
    assert int(sum([1.0 / 10] * 11) * 10) == 10  # ...and at 10 fps it is not


def test_missing_moviepy_is_one_line(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "moviepy" else real(name, *a))
    with pytest.raises(ConfigError, match=r"^video: video=true needs moviepy .*pip install 'cmdp_rl\[video\]'$"):
        make_render_env(Reach1DConfig())


# --- the gridworld (discrete actions, K = 2 costs) -----------------------------------------------
def test_grid_frame_is_drawn_where_the_agent_is():
    from cmdp_rl.envs.grid.env import AGENT_COLOUR, CELL_PX, GRID_COLOURS, GridWorld

    env = GridWorld(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (6 * CELL_PX, 7 * CELL_PX, 3) and frame.dtype == np.uint8
    centre = lambda r, c: (r * CELL_PX + CELL_PX // 2, c * CELL_PX + CELL_PX // 2)  # noqa: E731
    assert tuple(frame[centre(2, 0)]) == AGENT_COLOUR  # on S, the middle row's first cell
    assert tuple(frame[centre(2, 6)]) == GRID_COLOURS["G"] and tuple(frame[centre(2, 3)]) == GRID_COLOURS["a"]
    assert tuple(frame[centre(1, 2)]) == GRID_COLOURS["b"] and tuple(frame[centre(3, 3)]) == GRID_COLOURS["#"]
    assert tuple(frame[1, 1]) == GRID_COLOURS["."]  # no cost paid: no border
    env.cell = env.layout._index[(2, 2)]
    env.step(1)  # right, onto the 'a' cell unless it slips
    frame = env.render()
    r, c = env.layout.cells[env.cell]
    assert tuple(frame[centre(r, c)]) == AGENT_COLOUR
    if (r, c) == (2, 3):
        assert tuple(frame[1, 1]) == GRID_COLOURS["a"]  # hazard a's cost: an orange border
    assert GridWorld().render() is None
    with pytest.raises(ValueError, match="render_mode"):
        GridWorld(render_mode="human")


def test_grid_video_is_written_by_evaluate(tmp_path, capsys):
    raw = {
        "env": {"name": "grid", "num_envs": 2},
        "algo": {"name": "ppo_lag", "cost_limit": [0.3, 0.15], "update_epochs": 1, "num_minibatches": 2},
        "rollout_steps": 16,
        "total_steps": 32,
        "eval_episodes": 2,
    }
    train(load_config(raw), tmp_path / "run", echo=lambda _: None)
    assert evaluate_cli.main([f"run={tmp_path / 'run'}", "video=true", "video_steps=6", "episodes=2"]) == 0
    video = tmp_path / "run" / "videos" / "policy-episode-0.mp4"
    out = capsys.readouterr().out
    frames = int(out.split(f"wrote {video} (")[1].split(" frames")[0])
    assert 2 <= frames <= 7 and frames_in(video) == frames  # the reset frame and one per step, at most 6 steps
    assert "cost " in out and "/" in out.split(f"wrote {video}")[1]  # both costs, hazard_a/hazard_b


def test_a_saute_policy_sees_its_budget_state_in_the_video(tmp_path, monkeypatch):
    # Sauté's policy acts on (observation, remaining budget): the video's plain env must carry the
    # budget along as the training env does, z_{t+1} = z_t - c_t / d, restored at each episode's start.
    out = tmp_path / "run"
    cfg = tiny(total_steps=64, algo={"name": "saute", "update_epochs": 1, "num_minibatches": 2, "cost_limit": 0.5})
    del cfg["algo"]["multiplier"]
    train(load_config(cfg), out, echo=lambda s: None)
    from cmdp_rl.envs.saute import BudgetState

    episodes: list[list[tuple[float, float]]] = []  # per episode: (z the policy saw, the step's cost)
    start, observe = BudgetState.start, BudgetState.observe

    def spy_start(self):
        start(self)
        if self.z.shape[0] == 1:  # the video's one env (the evaluation's vector env resets its own)
            episodes.append([])

    def spy_observe(self, cost):
        episodes[-1].append((float(self.z[0, 0]), float(cost[0, 0])))
        observe(self, cost)

    monkeypatch.setattr(BudgetState, "start", spy_start)
    monkeypatch.setattr(BudgetState, "observe", spy_observe)
    assert evaluate_cli.main([f"run={out}", "video=true", "video_episodes=8", "episodes=2", "deterministic=false"]) == 0
    assert len(episodes) == 8
    for ep in episodes:
        z = 1.0  # each episode starts with the whole budget
        for seen_z, cost in ep:
            assert seen_z == pytest.approx(z)
            z -= cost / 0.5
    assert sum(c for ep in episodes for _, c in ep) > 0  # the budget did move (some episode crossed the wall)
