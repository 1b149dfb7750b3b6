"""Safety-Gymnasium's own tasks (``env=safety_gym env.task=SafetyPointGoal1-v0``), unchanged.

Built from the registered entry point and kwargs (``compat.py`` says why not by ``safety_gymnasium.make``);
:class:`SafetyGymTask` turns its six-value step into gymnasium's five, the cost in ``info["cost"]``, and
:class:`GymVecEnv` steps N of them (``env.vector=async``: in worker processes). Navigation tasks truncate at their step
limit and terminate only when the robot dies or the task says so (a goal reached is rewarded and replaced); velocity
tasks terminate as gymnasium's MuJoCo envs do."""

from __future__ import annotations

import importlib.util
import warnings
from functools import partial
from typing import Annotated, Any, Literal

import gymnasium as gym

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import ConfigError, Field, NonNegativeInt, PositiveInt, options, require
from cmdp_rl.envs.env_state import env_state, load_env_state
from cmdp_rl.envs.options import SAFETY_GYM_BUDGET, EnvOptions
from cmdp_rl.envs.safety_gym.compat import import_safety_gymnasium
from cmdp_rl.envs.safety_gym.tasks import TASKS, task_problem
from cmdp_rl.envs.safety_gym.world_state import load_world_state, world_state
from cmdp_rl.envs.vector import GymVecEnv, default_cost_names
from cmdp_rl.envs.velocity import RENDER_SIZE


class SafetyGymTask(gym.Env):
    """One Safety-Gymnasium task with gymnasium's five-value step (the cost in ``info["cost"]``)."""

    # Declared, so that the vector env builds no throwaway world to count the costs.
    cost_names = default_cost_names(1)

    def __init__(self, task: str, max_steps: int = 0, render_mode: str | None = None, **render_kwargs: Any) -> None:
        import_safety_gymnasium()
        from gymnasium.envs.registration import load_env_creator

        spec = gym.spec(task)
        kwargs = dict(spec.kwargs)
        if render_mode is not None:
            kwargs.update(render_mode=render_mode, **render_kwargs)
        with warnings.catch_warnings():
            # Its float32 Box spaces have float64 infinite bounds: numpy warns about the exact cast.
            warnings.filterwarnings("ignore", "overflow encountered in cast", RuntimeWarning)
            self.inner = load_env_creator(spec.entry_point)(**kwargs)
        self.limit = max_steps or spec.max_episode_steps
        self.steps = 0
        self.observation_space = self.inner.observation_space
        self.action_space = self.inner.action_space
        self.render_mode = render_mode
        self.metadata = dict(getattr(self.inner, "metadata", {}))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.steps = 0
        return self.inner.reset(seed=seed, options=options)

    def step(self, action):
        obs, reward, cost, terminated, truncated, info = self.inner.step(action)
        self.steps += 1
        info = dict(info)
        info["cost"] = float(cost)
        return obs, float(reward), bool(terminated), bool(truncated or self.steps >= self.limit), info

    def render(self):
        return self.inner.render()

    def close(self) -> None:
        self.inner.close()

    # Resume: a navigation task's world through world_state.py, a velocity task through envs/env_state.py.
    def state_dict(self) -> dict[str, Any]:
        if not hasattr(self.inner, "task"):  # a velocity task (a navigation task is a Builder)
            return {"steps": self.steps, "velocity": env_state(self.inner)}
        import mujoco

        return {"steps": self.steps, "world": world_state(self.inner), "mujoco": mujoco.__version__}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.steps = state["steps"]
        if "velocity" in state:
            load_env_state(self.inner, state["velocity"])
            return
        load_world_state(self.inner, state["world"])

    # gymnasium's vector envs set attributes one value per env (``set_attr``), also across processes.
    @property
    def saved_state(self) -> dict[str, Any]:
        return self.state_dict()

    @saved_state.setter
    def saved_state(self, state: dict[str, Any]) -> None:
        self.load_state_dict(state)


def make_task(task: str, max_steps: int = 0, render_mode: str | None = None, **render_kwargs: Any) -> SafetyGymTask:
    """One env of ``task``; ``render_kwargs`` (``width``, ``height``, ``camera_name``) go with a ``render_mode``."""
    problem = task_problem(task)
    if problem:
        raise ConfigError(problem)
    return SafetyGymTask(task, max_steps, render_mode, **render_kwargs)


# Navigation tasks film from behind and above the robot; the default camera, its own, shows little of the hazards.
NAVIGATION_CAMERA = "track"


@options
class SafetyGymEnvConfig(EnvOptions):
    """``env=safety_gym``: a Safety-Gymnasium 1.0.0 task (navigation or velocity), unchanged."""

    name: str = "safety_gym"
    backend: Literal["gym"] = "gym"
    num_envs: PositiveInt = 8
    task: Annotated[str, Field(pattern=r"\S", description="a Safety-Gymnasium task id")] = "SafetyPointGoal1-v0"
    max_steps: Annotated[NonNegativeInt, Field(description="an integer >= 0 (0: the task's limit)")] = 0
    vector: Literal["sync", "async"] = "sync"

    def budget(self) -> float:
        """d = 25 cost per episode, the field's budget for these tasks (``SAFETY_GYM_BUDGET``)."""
        return SAFETY_GYM_BUDGET

    def env_id(self) -> str:
        return self.task

    def render_env(self) -> SafetyGymTask:
        """One env of this task rendering ``rgb_array`` frames of RENDER_SIZE (for video)."""
        w, h = RENDER_SIZE
        camera = {} if "Velocity" in self.task else {"camera_name": NAVIGATION_CAMERA}
        return make_task(self.task, self.max_steps, render_mode="rgb_array", width=w, height=h, **camera)

    def episode_steps(self) -> int | None:
        return self.max_steps or TASKS.get(self.task)

    def check(self, run: Any) -> None:
        problem = task_problem(self.task)
        if problem:
            raise ConfigError(problem)
        limit = TASKS[self.task]
        allowed = f"in [0, {limit}] for {self.task} (0: its limit, {limit})"
        require(self.max_steps <= limit, "env.max_steps", allowed, self.max_steps)
        if importlib.util.find_spec("safety_gymnasium") is None:
            raise ConfigError("env.name: env=safety_gym needs Safety-Gymnasium: run `make setup-safety-gym`")


class SafetyGymVecEnv(GymVecEnv):
    """:class:`GymVecEnv` saving its envs' state through ``get_attr``/``set_attr``: worker processes too."""

    def state_dict(self) -> dict[str, Any]:
        return {"num_envs": self.num_envs, "envs": list(self.envs.get_attr("saved_state"))}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["num_envs"] != self.num_envs:
            raise ValueError(f"env: saved state is for {state['num_envs']} envs, this one has {self.num_envs}")
        self.envs.set_attr("saved_state", list(state["envs"]))


def make_safety_gym_vec_env(cfg: SafetyGymEnvConfig, num_envs: int, device: str = "cpu") -> SafetyGymVecEnv:
    return SafetyGymVecEnv(
        partial(make_task, cfg.task, cfg.max_steps), num_envs, device=device, asynchronous=cfg.vector == "async"
    )


register("env", "safety_gym", SafetyGymEnvConfig, make_safety_gym_vec_env)
