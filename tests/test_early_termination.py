"""The early-terminated MDP (``early_terminate: true``, envs/early_termination.py): a training episode
ends, as a termination, at the first step after which a cost's episode sum exceeds its budget; every
algorithm in the registry trains on it; evaluation episodes stay whole."""

import importlib.util

import gymnasium as gym
import pytest
import torch
import yaml
from helpers.cost_envs import TWO_COST_ID
from helpers.policies import ForwardPolicy
from helpers.resume import assert_same_run, crash_then_resume
from helpers.runs import metrics_rows, tiny

from cmdp_rl import Collector, finished_episodes, keys, load_config, train
from cmdp_rl.config.registry import component, names, register
from cmdp_rl.config.validation import ConfigError, PositiveInt, options
from cmdp_rl.envs import EarlyTerminated, GymVecEnv, Reach1D, TorchReach1D, make_env
from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.vector import Step, VecEnv
from cmdp_rl.population import population
from cmdp_rl.run.finish import evaluate_run
from cmdp_rl.run.start import build_run


def over_the_wall(obs):
    """Reach1D with wall=pass from 0.45, no noise: step across the wall at 0.5 and back, one crossing
    (cost 1) every step, never near the goal."""
    return torch.where(obs[:, :1] < 0.5, 0.1, -0.1)


REACH = {"max_steps": 100, "wall": "pass", "start": 0.45, "obs_noise": 0.0}


def _reach1d(backend):
    return GymVecEnv(lambda: Reach1D(**REACH), 3) if backend == "gymnasium" else TorchReach1D(3, **REACH)


@pytest.mark.parametrize("backend", ["gymnasium", "torch"])
def test_an_episode_ends_at_the_first_step_whose_cost_sum_exceeds_the_budget(backend):
    # d = 2.5: the sum is 1, 2, 3 after steps 1, 2, 3, so every episode is cut at step 3 (terminated).
    env = EarlyTerminated(_reach1d(backend), [2.5])
    batch = Collector(env, ForwardPolicy(over_the_wall), rollout_steps=10, seed=0).collect()
    nxt = batch[keys.NEXT]
    ends = torch.zeros(3, 10, dtype=torch.bool)
    ends[:, [2, 5, 8]] = True
    assert torch.equal(nxt[keys.TERMINATED].squeeze(-1), ends)
    assert torch.equal(nxt[keys.DONE].squeeze(-1), ends)
    assert not nxt[keys.TRUNCATED].any()
    episodes = finished_episodes(batch)
    assert episodes["length"].tolist() == [3.0] * 9
    assert episodes["cost"].squeeze(-1).tolist() == [3.0] * 9
    # the cut episode restarts from the task's start: the first crossing comes on the next step again
    assert torch.equal(nxt[keys.COST].squeeze(-1), torch.ones(3, 10))
    assert torch.allclose(batch[keys.OBS][:, 3, 0], torch.full((3,), 0.45))
    # at d = 3 the sum of 3 is within budget: the cut comes one step later
    batch = Collector(EarlyTerminated(_reach1d(backend), [3.0]), ForwardPolicy(over_the_wall), 10, seed=0).collect()
    assert finished_episodes(batch)["length"].tolist() == [4.0] * 6


def test_without_a_cut_the_same_episodes_run_on():
    batch = Collector(_reach1d("torch"), ForwardPolicy(over_the_wall), rollout_steps=10, seed=0).collect()
    assert not batch[keys.NEXT][keys.DONE].any()


class TwoCosts(VecEnv):
    """Two envs that never end, with scripted costs ``[N, 2]`` per step; ``starts`` counts the rows restarted."""

    num_envs, num_costs, obs_dim, action_dim = 2, 2, 1, 1
    action_low, action_high, device = torch.zeros(1), torch.ones(1), torch.device("cpu")

    def __init__(self, costs):
        self.costs, self.t, self.starts = costs, 0, torch.zeros(2, dtype=torch.int64)

    def reset(self, seed=None):
        return torch.zeros(2, 1)

    def reset_rows(self, rows):
        self.starts += rows.long()
        return torch.full((int(rows.sum()), 1), -1.0)

    def step(self, action):
        cost = torch.tensor(self.costs[self.t], dtype=torch.float32)
        self.t += 1
        no = torch.zeros(2, 1, dtype=torch.bool)
        return Step(torch.zeros(2, 1), torch.zeros(2, 1), cost, no, no, torch.zeros(2, 1))


def test_with_several_costs_the_episode_ends_when_any_cost_passes_its_budget():
    # budgets (1, 2): row 0 passes cost 0's at step 2, row 1 cost 1's at step 3; then their sums start again
    env = EarlyTerminated(TwoCosts([[[0.6, 0], [0, 0.9]], [[0.6, 0], [0, 0.9]], [[0, 0], [0, 0.9]]]), [1.0, 2.0])
    ended = [env.step(torch.zeros(2, 1)) for _ in range(3)]
    assert [s.terminated.view(-1).tolist() for s in ended] == [[False, False], [True, False], [False, True]]
    assert ended[1].obs.view(-1).tolist() == [-1.0, 0.0]  # the restarted row's first observation
    assert env.env.starts.tolist() == [1, 1]
    assert env.spent.tolist() == [[0.0, 0.0], [0.0, 0.0]]


def test_a_budget_list_of_the_wrong_length_is_a_config_error():
    with pytest.raises(ConfigError, match="algo.cost_limit must be a number or a list of 2 numbers"):
        make_env(load_config({"env": {"name": "grid"}}).env, cut_at=[1.0, 2.0, 3.0])


class NoPartialReset(TwoCosts):
    reset_rows = VecEnv.reset_rows


@options
class NoRestartConfig(EnvOptions):
    name: str = "toy_no_restart"
    num_envs: PositiveInt = 2


class NoRestart(VecEnv):
    """An env without ``reset_rows``: one step episodes, no cost."""

    num_envs, obs_dim, action_dim = 2, 1, 1
    action_low, action_high, device = -torch.ones(1), torch.ones(1), torch.device("cpu")

    def reset(self, seed=None):
        return torch.zeros(2, 1)

    def step(self, action):
        end, no = torch.ones(2, 1, dtype=torch.bool), torch.zeros(2, 1, dtype=torch.bool)
        return Step(torch.zeros(2, 1), torch.zeros(2, 1), torch.zeros(2, 1), end, no, torch.zeros(2, 1))


register("env", "toy_no_restart", NoRestartConfig, lambda cfg, num_envs, device="cpu": NoRestart())


def test_an_env_that_cannot_restart_one_episode_is_refused_in_one_line_before_anything_is_written(tmp_path, quiet):
    with pytest.raises(ConfigError, match="early_terminate: true needs an env that can restart single episodes"):
        EarlyTerminated(NoPartialReset([]), [1.0])
    cfg = load_config({"env": {"name": "toy_no_restart"}, "algo": {"name": "ppo"}, "early_terminate": True})
    with pytest.raises(ConfigError) as refused:
        train(cfg, tmp_path / "run", echo=quiet)
    assert "\n" not in str(refused.value) and "NoRestart has none" in str(refused.value)
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())
    train(
        load_config({"env": {"name": "toy_no_restart"}, "algo": {"name": "ppo"}, "total_steps": 64}),
        tmp_path / "ok",
        echo=quiet,
    )


# Every env family beyond Reach1D (whose episodes the first test counts step by step).
FAMILIES = {
    "suite": {"name": "suite", "num_envs": 4},
    "fork": {"name": "fork", "num_envs": 4},
    "fork_torch": {"name": "fork", "num_envs": 4, "backend": "torch"},
    "grid": {"name": "grid", "num_envs": 4},
    "skills": {"name": "skills", "num_envs": 4, "hold": 2},
    "pettingzoo": {"name": "pettingzoo", "num_envs": 2},
    "safe_nav": {"name": "safe_nav", "num_envs": 2, "task": "PointGoal1"},
    "gym": {"name": "gym", "num_envs": 3, "id": TWO_COST_ID},  # K = 2 costs
    "velocity": {"name": "velocity", "num_envs": 2},
    "safety_gym": {"name": "safety_gym", "num_envs": 2, "vector": "sync"},
}
NEEDS = {"safe_nav": "mujoco", "velocity": "mujoco", "safety_gym": "safety_gymnasium"}


def _random_steps(env, steps):
    torch.manual_seed(0)
    for _ in range(steps):
        low, high = env.action_low, env.action_high
        action = low + (high - low) * torch.rand(env.num_envs, env.action_dim)
        if not isinstance(env.action_space, gym.spaces.Box):
            action = action.round()
        yield env.step(action)


@pytest.mark.parametrize("family", FAMILIES)
def test_every_env_family_is_cut_at_the_budget(family):
    if family in NEEDS and importlib.util.find_spec(NEEDS[family]) is None:
        pytest.skip(f"{family} needs {NEEDS[family]}")
    cfg = load_config({"env": FAMILIES[family], "algo": {"name": "ppo"}})
    env = make_env(cfg.env, cut_at=0.0)  # d = 0: every step with a cost ends its episode
    env.reset(seed=0)
    for s in _random_steps(env, 30):
        over = (s.cost > 0).any(-1, keepdim=True)
        assert torch.equal(s.terminated & over, over) and not (s.truncated & over).any()
    env.close()
    # A budget below 0 is passed at every step: every row restarts every step, through the env's
    # reset_rows, and its next observation is a first one (where the start is fixed: the reset's).
    env = make_env(cfg.env, cut_at=-1.0)
    first = env.reset(seed=0)
    fixed = bool((first == first[:1]).all()) and family not in ("pettingzoo",)
    for s in _random_steps(env, 5):
        assert s.terminated.all() and not s.truncated.any()
        if fixed:
            assert torch.equal(s.obs, first)
    env.close()


def test_training_cuts_episodes_and_evaluation_runs_whole_ones(tmp_path, quiet):
    cfg = load_config(
        {
            "env": {"name": "reach1d", "num_envs": 2, **REACH, "max_steps": 12},
            "algo": {"name": "ppo", "cost_limit": 2.5},
        }
    )
    cfg.early_terminate = True
    env, _, _ = build_run(cfg)
    assert isinstance(env, EarlyTerminated)
    env.close()
    result = evaluate_run(cfg, ForwardPolicy(over_the_wall))
    assert result["episode_length"] == 12.0  # whole episodes: 12 steps, 12 crossings, far over the budget
    assert result["episode_cost"] == 12.0


ALGOS = names("algo")


def _enrolled(algo):
    """helpers.runs' TINY run with ``algo``'s tiny options, d = 0.2, starts beside the wall (crossings come
    early: every training episode that crosses passes the budget), or the algorithm's own tiny env."""
    cfg = tiny(total_steps=96, early_terminate=True)
    cfg["env"]["start"] = [0.46, 0.54]
    own = component("algo", algo).options
    if own.tiny_env:
        cfg["env"] = dict(own.tiny_env)
    cfg["algo"] = {"name": algo, **own.tiny, "cost_limit": 0.2}
    return cfg


def _cut(env):
    while not isinstance(env, EarlyTerminated) and hasattr(env, "env"):
        env = env.env  # an algorithm's own wrapper (Sauté's budget state) holds the cut env
    return isinstance(env, EarlyTerminated)


@pytest.mark.parametrize("algo", ALGOS)
def test_every_registered_algorithm_trains_on_the_early_terminated_mdp(algo, tmp_path, quiet, monkeypatch):
    batches = []
    collect = Collector.collect

    def recording(self):
        batch = collect(self)
        if _cut(self.env):  # the training collector's; evaluation's env is whole
            batches.append(batch)
        return batch

    monkeypatch.setattr(Collector, "collect", recording)
    lines = []
    train(load_config(_enrolled(algo)), tmp_path, echo=lines.append)
    assert "cost limit 0.2 (algo.cost_limit), training episodes end past it (early_terminate)" in lines[0]
    assert batches, "training collected from the cut env"
    over = 0
    for batch in batches:
        nxt = batch[keys.NEXT]
        passed = (nxt[keys.EPISODE_COST] > 0.2).any(-1)
        assert torch.equal(nxt[keys.TERMINATED].squeeze(-1) & passed, passed)  # where the sum passes d, it ends
        over += int(passed.sum())
    assert over > 0, "some training episode passed the budget (the check is not vacuous)"


@pytest.mark.parametrize("env", [{"backend": "torch", "stagger": True}, {"name": "fork", "backend": "torch"}])
def test_a_population_s_agents_train_as_their_single_runs_on_the_early_terminated_mdp(tmp_path, env, quiet):
    """Reach1D's population form (one env of P N rows, each agent's rows cut at its own budget) and
    the agents' own envs stepped in turn (the fork): each agent equals train() on its config.yaml."""
    raw = tiny(env={"num_envs": 4, **env}, total_steps=4 * 64, early_terminate=True)
    if env.get("name") == "fork":
        raw["env"] = {"name": "fork", "num_envs": 4, "backend": "torch"}
    raw["population"] = {"seeds": 1, "grid": {"algo": {"cost_limit": [0.2, 0.5]}}}
    train(population(raw), tmp_path / "pop", echo=quiet)
    for i, d in enumerate(sorted((tmp_path / "pop" / "agents").iterdir())):
        cfg = load_config(yaml.safe_load((d / "config.yaml").read_text()))
        assert cfg.early_terminate
        train(cfg, tmp_path / f"single{i}", echo=quiet)
        rows, expected = metrics_rows(d), metrics_rows(tmp_path / f"single{i}")
        assert [r["episode_length"] for r in rows] == [r["episode_length"] for r in expected]
        assert [r["episode_cost"] for r in rows] == [r["episode_cost"] for r in expected]


@pytest.mark.parametrize("env", [{}, {"backend": "torch", "stagger": True}])
def test_a_crashed_run_resumes_as_the_uninterrupted_one(env, tmp_path, monkeypatch, quiet):
    # d = 1.5: an episode holds one crossing's cost without being cut, so a checkpoint holds running sums
    cfg = tiny(early_terminate=True, env={**env, "start": [0.46, 0.54]})
    cfg["algo"]["cost_limit"] = 1.5
    assert_same_run(*crash_then_resume(cfg, tmp_path, monkeypatch, quiet))
