"""Safety-Gymnasium's own tasks (``env=safety_gym env.task=SafetyPointGoal1-v0``).

The task is Safety-Gymnasium 1.0.0's, unchanged: built from its registered entry point and kwargs
(``safety_gym_compat.py`` says why not by ``safety_gymnasium.make``, and what it takes to import the
package on our stack). :class:`SafetyGymTask` adapts it to gymnasium's five-value step: the cost,
the third value of Safety-Gymnasium's six-value step, goes to ``info["cost"]``, where every env of
this toolkit reports it. From there it is an env like any other: :class:`GymVecEnv` steps N of them
(in this process or, with ``env.vector=async``, in worker processes), and the collector keeps the
reward and cost twins, bootstraps truncated episodes from their final observation and sums episodes.

Episode ends, as the package defines them: navigation tasks truncate at their step limit (1000;
Circle and Run 500) and terminate only when the robot dies (Ant, Doggo falling over) or a task
says so; a goal reached is rewarded and a new goal placed, the episode goes on. Velocity tasks are
gymnasium's MuJoCo v4 envs with the package's cost, terminating as those envs do.
"""

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

INSTALL = "env=safety_gym needs Safety-Gymnasium: run `make setup-safety-gym`"


class SafetyGymTask(gym.Env):
    """One Safety-Gymnasium task with gymnasium's step: ``(obs, reward, terminated, truncated,
    info)``, the step's cost in ``info["cost"]``.

    ``max_steps`` (0: the task's registered limit) truncates episodes; a navigation task also
    truncates itself at its own limit, so a larger value has no effect (the config refuses it).
    """

    # One cost per task. Declared, so that the vector env need not build a throwaway world to
    # count them (a world build is about 0.5 s: a probe env cost each make_env that much).
    cost_names = default_cost_names(1)

    def __init__(self, task: str, max_steps: int = 0, render_mode: str | None = None, **render_kwargs: Any) -> None:
        import_safety_gymnasium()
        from gymnasium.envs.registration import load_env_creator

        spec = gym.spec(task)
        kwargs = dict(spec.kwargs)
        if render_mode is not None:
            kwargs.update(render_mode=render_mode, **render_kwargs)
        with warnings.catch_warnings():
            # Its Box spaces declare float32 observations with float64 infinite bounds: numpy warns
            # about the cast, which is exact (inf stays inf).
            warnings.filterwarnings("ignore", "overflow encountered in cast", RuntimeWarning)
            self.inner = load_env_creator(spec.entry_point)(**kwargs)
        self.task_id = task
        self.limit = max_steps or spec.max_episode_steps
        self.steps = 0
        self.observation_space = self.inner.observation_space
        self.action_space = self.inner.action_space
        self.render_mode = render_mode
        self.metadata = dict(getattr(self.inner, "metadata", {}))

    @property
    def navigation(self) -> bool:
        return hasattr(self.inner, "task")  # safety_gymnasium.builder.Builder

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

    # -- saving an episode in progress (resume) -------------------------------------------------
    # A navigation task's world is saved as its fields and MuJoCo's arrays (world_state.py): restored
    # runs continue bit for bit (tests/test_safety_gym.py). Velocity tasks are plain gymnasium
    # MuJoCo envs: envs/env_state.py saves them.

    def state_dict(self) -> dict[str, Any]:
        if not self.navigation:
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
    """One env of ``task`` (a Safety-Gymnasium id this module offers); ``render_kwargs`` (frame
    ``width``, ``height``, ``camera_name``) go to the task with a ``render_mode``."""
    problem = task_problem(task)
    if problem:
        raise ConfigError(problem)
    return SafetyGymTask(task, max_steps, render_mode, **render_kwargs)


# Video frames (width, height): multiples of 16, as video encoders like. Navigation tasks film from
# the package's "track" camera (behind and above the robot, following it); its default, "vision",
# is the robot's own front camera, which shows little of the hazards around it.
RENDER_SIZE = (320, 240)
NAVIGATION_CAMERA = "track"


@options
class SafetyGymEnvConfig(EnvOptions):
    """``env=safety_gym``: a Safety-Gymnasium 1.0.0 task (navigation or velocity), as the package
    defines it; cost 1 on each step that violates the task's constraint."""

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
        require(
            self.max_steps <= limit,
            "env.max_steps",
            f"in [0, {limit}] for {self.task} (0: its limit, {limit})",
            self.max_steps,
        )
        if importlib.util.find_spec("safety_gymnasium") is None:
            raise ConfigError(f"env.name: {INSTALL}")


class SafetyGymVecEnv(GymVecEnv):
    """:class:`GymVecEnv` whose envs' state goes through gymnasium's ``get_attr``/``set_attr``, so
    that envs in worker processes (``env.vector=async``) save and restore theirs too."""

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

__all__ = ["SafetyGymEnvConfig", "SafetyGymTask", "SafetyGymVecEnv", "make_safety_gym_vec_env", "make_task"]
