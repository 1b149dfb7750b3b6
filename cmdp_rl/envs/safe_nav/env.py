"""Safety-Gymnasium's navigation tasks, N at a time: ``env=safe_nav env.task=PointGoal1``.

The same tasks as ``env=safety_gym`` (Safety-Gymnasium 1.0.0's), rebuilt for speed and equal to them step for step
(tests/test_safe_nav.py; docs/safe_nav.md): physics compiled once, N worlds stepped in one loop (``world.py``, or MuJoCo
Warp with ``env.physics=mjwarp``: ``warp_world.py``); layouts drawn from the reference's random streams (``layout.py``);
each family's reward, cost and lidar written once over the N envs (``FAMILIES``). This module: the batch itself (physics
step, the robot's sensors, time limit, per-env automatic reset, resume)."""

from __future__ import annotations

from typing import Annotated, Any, Literal, Sequence

import numpy as np
import torch

from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import ConfigError, Field, PositiveInt, options, require
from cmdp_rl.envs.options import SAFETY_GYM_BUDGET, EnvOptions
from cmdp_rl.envs.safe_nav.arrays import namespace, to_host
from cmdp_rl.envs.safe_nav.button import ButtonTask
from cmdp_rl.envs.safe_nav.circle import CircleTask
from cmdp_rl.envs.safe_nav.goal import GoalTask
from cmdp_rl.envs.safe_nav.layout import LayoutSampler
from cmdp_rl.envs.safe_nav.lidar import LIDAR_BINS
from cmdp_rl.envs.safe_nav.push import PushTask
from cmdp_rl.envs.safe_nav.spec import ROBOTS, nav_spec
from cmdp_rl.envs.safe_nav.warp_world import WARP_TASKS, WarpWorlds, warp_problem
from cmdp_rl.envs.safe_nav.world import NavWorlds
from cmdp_rl.envs.vector import Step, VecEnv

# task family -> its logic (a module each)
FAMILIES = {"Goal": GoalTask, "Circle": CircleTask, "Button": ButtonTask, "Push": PushTask}
TASKS = tuple(f"{robot}{family}{level}" for family in FAMILIES for robot in ROBOTS for level in (0, 1, 2))


def task_problem(task: str, physics: str = "mujoco") -> str | None:
    """None if ``env=safe_nav`` offers ``task`` on ``physics``, else the one-line config error saying why not."""
    if task in TASKS and physics == "mjwarp" and task not in WARP_TASKS:
        return f"env.physics: mjwarp offers {', '.join(WARP_TASKS)}, not {task} (env.physics=mujoco runs it)"
    if task in TASKS:
        return warp_problem() if physics == "mjwarp" else None
    plain = task.removeprefix("Safety").split("-v")[0]
    if plain in TASKS:
        return f"env.task: safe_nav names tasks without prefix and version: use env.task={plain}"
    if "Run" in plain or plain.startswith(("Racecar", "Doggo", "Ant")):
        return (
            f"env.task: {plain!r} is not implemented in safe_nav yet (offered: {', '.join(TASKS)}); "
            f"env=safety_gym runs it (slowly) as Safety{plain}-v0"
        )
    return f"env.task must be one of {', '.join(TASKS)}, got {task!r}"


def _sensor_plan(model) -> list[tuple[str, int, int]]:
    """(how, address, size) of each observed sensor, in the reference's order: the four named sensors,
    hinge and ball velocities, hinge angles (as sin, cos) and ball joints (as rotation matrices)."""
    import mujoco

    s = mujoco.mjtSensor
    by_name = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SENSOR, i): i for i in range(model.nsensor)}
    plan = [("raw", by_name[n]) for n in ("accelerometer", "velocimeter", "gyro", "magnetometer")]
    joint_sensors = [i for i in range(model.nsensor) if model.sensor_objtype[i] == mujoco.mjtObj.mjOBJ_JOINT]
    hinge = [i for i in joint_sensors if model.jnt_type[model.sensor_objid[i]] == mujoco.mjtJoint.mjJNT_HINGE]
    plan += [("raw", i) for i in hinge if model.sensor_type[i] == s.mjSENS_JOINTVEL]
    plan += [("raw", i) for i in joint_sensors if model.sensor_type[i] == s.mjSENS_BALLANGVEL]
    plan += [("sincos", i) for i in hinge if model.sensor_type[i] == s.mjSENS_JOINTPOS]
    plan += [("quatmat", i) for i in joint_sensors if model.sensor_type[i] == s.mjSENS_BALLQUAT]
    return [(how, int(model.sensor_adr[i]), int(model.sensor_dim[i])) for how, i in plan]


def _quat_mat(q):
    """Rotation matrices ``[N, 9]`` (row-major) of unit quaternions ``[N, 4]`` (w, x, y, z)."""
    w, x, y, z = q.T
    row0 = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]
    row1 = [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]
    row2 = [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
    return namespace(q).stack(row0 + row1 + row2, axis=-1)


class SafeNavVecEnv(VecEnv):
    """N instances of one navigation task, one batch: on the CPU or on MuJoCo Warp (``physics``) on ``device``."""

    def __init__(
        self,
        task: str,
        num_envs: int,
        max_steps: int = 0,
        device: str | torch.device = "cpu",
        threads: int = 1,
        physics: str = "mujoco",
    ) -> None:
        problem = task_problem(task, physics)
        if problem:
            raise ConfigError(problem)
        self.task = task
        self.physics = physics
        self.spec = nav_spec(task)
        self.num_envs = num_envs
        self.device = torch.device(device)
        if physics == "mjwarp":
            self.worlds = WarpWorlds(self.spec, num_envs, self.device)
        else:
            self.worlds = NavWorlds(self.spec, num_envs, threads)
        self.sampler = LayoutSampler(self.spec, num_envs)
        self.world_seeds: list[int] | None = None  # reset(None)'s seeds, one per world, if set
        self.logic = FAMILIES[self.spec.family](self.worlds, self.sampler)
        self.max_steps = max_steps or self.logic.episode
        w = self.worlds
        self.sensors = _sensor_plan(w.models[0])
        self.action_dim = len(w.ctrl_low)
        self.action_low = torch.as_tensor(w.ctrl_low, dtype=torch.float32, device=self.device)
        self.action_high = torch.as_tensor(w.ctrl_high, dtype=torch.float32, device=self.device)
        sizes = {"raw": None, "sincos": 2, "quatmat": 9}
        self.obs_dim = sum(sizes[how] or dim for how, _, dim in self.sensors) + LIDAR_BINS * self.logic.lidar_groups
        self.layouts: list[dict[str, Any]] = [{} for _ in range(num_envs)]
        self.steps = np.zeros(num_envs, dtype=np.int64)

    def close(self) -> None:
        self.worlds.close()

    def _obs(self, envs, world: dict):
        sd = world["sensordata"]
        xp = namespace(sd)
        cols = []
        for how, adr, dim in self.sensors:
            if how == "raw":
                cols.append(sd[:, adr : adr + dim])
            elif how == "sincos":
                cols += [xp.sin(sd[:, adr : adr + 1]), xp.cos(sd[:, adr : adr + 1])]
            else:
                cols.append(_quat_mat(sd[:, adr : adr + 4]))
        cols += self.logic.lidars(envs, world)
        return xp.concatenate(cols, axis=1)

    def _start(self, envs: list[int], layouts: list[dict[str, Any]] | None = None):
        """New episodes for ``envs`` (from new layouts, or the ones given); their first observations."""
        if layouts is None:
            layouts = [self.sampler.layout(i) for i in envs]
        for i, layout in zip(envs, layouts):
            self.layouts[i] = layout
            self.worlds.place(i, layout)
        self.steps[envs] = 0
        world = self.worlds.gather(envs)
        self.logic.start(envs, layouts, world)
        return self._obs(envs, world)

    def reset(self, seed: int | None = None) -> torch.Tensor:
        if seed is not None:
            seeds = [seed + i for i in range(self.num_envs)]
        elif self.world_seeds is not None:  # a population's worlds: each agent's seeded as its own run's
            seeds = list(self.world_seeds)
        else:
            seeds = [int(s) for s in np.random.randint(2**32, size=self.num_envs, dtype=np.int64)]
        self.sampler.seed(seeds)
        return self._tensor(self._start(list(range(self.num_envs))))

    def _tensor(self, x, dtype=torch.float32) -> torch.Tensor:
        if isinstance(x, torch.Tensor):  # mjwarp: already on the device
            return x.to(dtype=dtype, device=self.device)
        return torch.from_numpy(np.ascontiguousarray(x)).to(dtype=dtype, device=self.device)

    def reset_rows(self, rows: torch.Tensor) -> torch.Tensor:
        return self._tensor(self._start([int(i) for i in torch.nonzero(rows.view(-1)).view(-1).tolist()]))

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        n, every = self.num_envs, slice(None)
        warp = self.physics == "mjwarp"
        self.worlds.step(action.detach() if warp else action.detach().cpu().numpy().astype(np.float64))
        self.sampler.pending += 1  # the reference's per-step draw
        world = self.worlds.gather(every)
        reward, cost, terminated = self.logic.step(world)
        self.steps += 1
        truncated = self.steps >= self.max_steps
        obs = next_obs = self._obs(every, world)
        next_obs_t = obs_t = self._tensor(next_obs)
        done = np.flatnonzero(to_host(terminated) | truncated)
        if len(done):
            obs = next_obs.clone() if warp else next_obs.copy()
            obs[done] = self._start(list(done))
            obs_t = self._tensor(obs)
        self.last = {"next_obs": next_obs, "reward": reward, "obs": obs}  # float64, for fidelity checks
        if warp:
            signals = torch.stack([self._tensor(reward), self._tensor(cost)])
            ends = torch.stack([self._tensor(terminated, torch.bool), self._tensor(truncated, torch.bool)])
        else:  # one conversion for the floats and one for the flags (a cost flag stacks as 0.0 or 1.0)
            signals = self._tensor(np.stack([reward, cost]))
            ends = self._tensor(np.stack([terminated, truncated]), torch.bool)
        return Step(
            next_obs=next_obs_t,
            reward=signals[0].view(n, 1),
            cost=signals[1].view(n, 1),
            terminated=ends[0].view(n, 1),
            truncated=ends[1].view(n, 1),
            obs=obs_t,
        )

    def state_dict(self) -> dict[str, Any]:
        """Layouts, task state, MuJoCo states, step counters and random streams: a restored env continues exactly."""
        return {
            "num_envs": self.num_envs,
            "task": self.task,
            "physics": self.physics,
            "layouts": self.layouts,
            "steps": self.steps.copy(),
            "mujoco": list(self.worlds.get_states()),
            "sampler": self.sampler.state_dict(),
            **self.logic.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        saved_physics = state.get("physics", "mujoco")
        if state["num_envs"] != self.num_envs or state["task"] != self.task or saved_physics != self.physics:
            raise ValueError(
                f"env: saved state is for {state['num_envs']} envs of {state['task']} on {saved_physics}, "
                f"this one has {self.num_envs} of {self.task} on {self.physics}"
            )
        for i, layout in enumerate(state["layouts"]):
            self.layouts[i] = layout
            self.worlds.place(i, layout)
        self.logic.load_state_dict(state, self.layouts)
        self.worlds.set_states(state["mujoco"])
        self.steps[:] = state["steps"]
        self.sampler.load_state_dict(state["sampler"])


@options
class SafeNavEnvConfig(EnvOptions):
    """``env=safe_nav``: Safety-Gymnasium's navigation tasks, batched (this module)."""

    name: str = "safe_nav"
    num_envs: PositiveInt = 16
    task: Annotated[str, Field(pattern=r"\S", description="a navigation task, e.g. PointGoal1")] = "PointGoal1"
    max_steps: Annotated[int, Field(ge=0, description="an integer >= 0 (0: the task's limit)")] = 0
    threads: PositiveInt = 1
    physics: Literal["mujoco", "mjwarp"] = "mujoco"

    def budget(self) -> float:
        """d = 25 cost per episode, the field's budget for these tasks (``SAFETY_GYM_BUDGET``)."""
        return SAFETY_GYM_BUDGET

    def env_id(self) -> str:
        return f"safe_nav/{self.task}"

    def episode_steps(self) -> int | None:
        return self.max_steps or (FAMILIES[nav_spec(self.task).family].episode if not task_problem(self.task) else None)

    def check(self, run: Any) -> None:
        problem = task_problem(self.task, self.physics)
        if problem:
            raise ConfigError(problem)
        episode = FAMILIES[nav_spec(self.task).family].episode
        require(self.max_steps <= episode, "env.max_steps", f"in [0, {episode}] (0: the task's limit)", self.max_steps)
        import importlib.util

        if importlib.util.find_spec("safety_gymnasium") is None or importlib.util.find_spec("mujoco") is None:
            raise ConfigError(
                "env.name: env=safe_nav reads the robots' models from Safety-Gymnasium: run `make setup-safety-gym`"
            )

    def population_env(
        self, env_cfgs: Sequence[Any], num_envs: int, seeds: Sequence[int], device: Any, evaluation: bool
    ) -> SafeNavVecEnv:
        """P agents' worlds as one batch of P N worlds, agent i's world j seeded ``seeds[i] + j`` as
        ``reset(seeds[i])`` seeds its single run's: each world draws from its own stream."""
        env = make_safe_nav_vec_env(self, num_envs * len(env_cfgs), device)
        env.world_seeds = [int(s) + j for s in seeds for j in range(num_envs)]
        return env

    def render_env(self):
        """The reference task drawing ``rgb_array`` frames (video): the same layouts and trajectories."""
        from cmdp_rl.envs.safety_gym.env import make_task

        return make_task(f"Safety{self.task}-v0", self.max_steps, render_mode="rgb_array")


def make_safe_nav_vec_env(cfg: SafeNavEnvConfig, num_envs: int, device: str = "cpu") -> SafeNavVecEnv:
    return SafeNavVecEnv(cfg.task, num_envs, cfg.max_steps, device=device, threads=cfg.threads, physics=cfg.physics)


register("env", "safe_nav", SafeNavEnvConfig, make_safe_nav_vec_env)
