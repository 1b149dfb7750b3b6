"""Safety-Gymnasium's navigation tasks, N at a time: ``env=safe_nav env.task=PointGoal1``.

The same tasks as ``env=safety_gym`` (Safety-Gymnasium 1.0.0's), rebuilt for speed: there, one
navigation step costs a few milliseconds of Python (lidar object by object, name look-ups) and every
reset recompiles the MuJoCo model; physics is a tenth of it. Here:

- physics: the robot's own MuJoCo model and the same world, compiled once, N copies stepped in one
  loop (``safe_nav_world.py``); integrating the same state with the same controls gives the same
  numbers, bit for bit (tests/test_safe_nav.py);
- layouts: drawn as the reference draws them, from one random stream per env seeded as gymnasium
  seeds a vector env, so a seed gives the reference's layouts (``safe_nav_layout.py``);
- the task (reward, cost, observation, goal reached, time limit): numpy over the N envs, below.

The task, as Safety-Gymnasium 1.0.0 defines its Goal tasks (facts from its source, our code):
reward = (last distance to goal - distance now) + 1 on reaching it (distance <= 0.3), clipped to
[-10, 10]; a goal reached is replaced by a new one (the episode goes on; if no place is found the
episode terminates). Cost = 1 on a step where the robot is inside a hazard (xy distance < 0.2) or,
at level 2, touches a vase or a vase moves (speed >= 1e-4); else 0. Observation: the robot's
accelerometer, velocimeter, gyro and magnetometer (Car adds its rear ball joint's angular velocity
and rotation matrix), then a 16-bin pseudo-lidar per object kind (goal, hazards, vases): each object
lights the bin of its egocentric angle with ``max(0, 3 - d) / 3`` (d its xy distance) and its two
neighbours in proportion to where in the bin it lies; the closest wins. Episodes truncate at 1000
steps.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

import numpy as np
import torch

from cmdp_rl.envs.options import EnvOptions
from cmdp_rl.envs.safe_nav_layout import LayoutSampler
from cmdp_rl.envs.safe_nav_world import (AGENT_KEEPOUT, GOAL_SIZE, HAZARD_KEEPOUT, HAZARD_SIZE, ROBOTS,
                                         VASE_KEEPOUT, NavWorlds, nav_spec)
from cmdp_rl.envs.vector import Step, VecEnv
from cmdp_rl.registry import register
from cmdp_rl.validation import ConfigError, Field, PositiveInt, options, require

TASKS = tuple(f"{robot}Goal{level}" for robot in ROBOTS for level in (0, 1, 2))
EPISODE = 1000
LIDAR_BINS, LIDAR_MAX = 16, 3.0
REWARD_CLIP = 10.0
VASE_SPEED = 1e-4  # a vase moving at least this fast costs (level 2)
_NOT_YET = ("Button", "Push", "Circle", "Run")
_OTHER_ROBOTS = ("Racecar", "Doggo", "Ant")


def task_problem(task: str) -> str | None:
    """None if ``env=safe_nav`` offers ``task``, else the one-line config error saying why not."""
    if task in TASKS:
        return None
    plain = task.removeprefix("Safety").split("-v")[0]
    if plain in TASKS:
        return f"env.task: safe_nav names tasks without prefix and version: use env.task={plain}"
    if any(f in plain for f in _NOT_YET) or any(plain.startswith(r) for r in _OTHER_ROBOTS):
        return (f"env.task: {plain!r} is not implemented in safe_nav yet (offered: {', '.join(TASKS)}); "
                f"env=safety_gym runs it (slowly) as Safety{plain}-v0")
    return f"env.task must be one of {', '.join(TASKS)}, got {task!r}"


def _sensor_plan(model) -> list[tuple[str, int, int]]:
    """(how, address, size) of each observed sensor, in the reference's observation order: the four
    named sensors, hinge velocities, ball angular velocities, then hinge angles (as sin, cos) and
    ball joints (as rotation matrices)."""
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


def _quat_mat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[N, 9]`` (row-major) of unit quaternions ``[N, 4]`` (w, x, y, z)."""
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)


def pseudo_lidar(objects_xy: np.ndarray, agent_pos: np.ndarray, agent_mat: np.ndarray) -> np.ndarray:
    """Safety-Gymnasium's pseudo-lidar of M objects per env: ``objects_xy`` ``[N, M, 2]``,
    the robot's position ``[N, 3]`` and frame ``[N, 3, 3]`` -> ``[N, 16]``."""
    n, m = objects_xy.shape[:2]
    out = np.zeros((n, LIDAR_BINS))
    if m == 0:
        return out
    world = np.concatenate([objects_xy, np.zeros((n, m, 1))], axis=-1) - agent_pos[:, None, :]
    ego = np.matmul(world, agent_mat)  # the offset in the robot's frame (row vector times frame)
    dist = np.hypot(ego[..., 0], ego[..., 1])
    angle = np.arctan2(ego[..., 1], ego[..., 0]) % (2 * np.pi)
    width = 2 * np.pi / LIDAR_BINS
    bins = (angle / width).astype(np.int64) % LIDAR_BINS
    reading = np.maximum(0.0, LIDAR_MAX - dist) / LIDAR_MAX
    alias = (angle - width * bins) / width  # where in its bin: it lights the neighbours in proportion
    rows = np.broadcast_to(np.arange(n)[:, None], bins.shape)
    np.maximum.at(out, (rows, bins), reading)
    np.maximum.at(out, (rows, (bins + 1) % LIDAR_BINS), alias * reading)
    np.maximum.at(out, (rows, (bins - 1) % LIDAR_BINS), (1 - alias) * reading)
    return out


class SafeNavVecEnv(VecEnv):
    """N instances of one navigation task (module docstring), stepped as one batch on the CPU;
    tensors handed out live on ``device``."""

    def __init__(self, task: str, num_envs: int, max_steps: int = 0, device: str | torch.device = "cpu",
                 threads: int = 1) -> None:
        problem = task_problem(task)
        if problem:
            raise ConfigError(problem)
        self.task = task
        self.spec = nav_spec(task)
        self.num_envs = num_envs
        self.max_steps = max_steps or EPISODE
        self.device = torch.device(device)
        self.worlds = NavWorlds(self.spec, num_envs, threads)
        self.sampler = LayoutSampler(self.spec, num_envs)
        w = self.worlds
        self.sensors = _sensor_plan(w.models[0])
        self.action_dim = len(w.ctrl_low)
        self.action_low = torch.as_tensor(w.ctrl_low, dtype=torch.float32, device=self.device)
        self.action_high = torch.as_tensor(w.ctrl_high, dtype=torch.float32, device=self.device)
        sizes = {"raw": None, "sincos": 2, "quatmat": 9}
        self.obs_dim = sum(sizes[how] or dim for how, _, dim in self.sensors)
        self.obs_dim += LIDAR_BINS * (1 + (self.spec.level > 0) * 2)
        n, h = num_envs, self.spec.hazards
        self.layouts: list[dict[str, Any]] = [{} for _ in range(n)]
        self.goal = np.zeros((n, 2))
        self.hazards = np.zeros((n, h, 2))
        self.last_dist = np.zeros(n)
        self.steps = np.zeros(n, dtype=np.int64)

    def close(self) -> None:
        self.worlds.close()

    # --- reading the worlds -------------------------------------------------------------------
    def _gather(self, envs) -> dict[str, np.ndarray]:
        w = self.worlds
        datas = [w.datas[i] for i in envs]
        xpos = np.stack([d.xpos for d in datas])
        mat = np.stack([d.xmat[w.agent] for d in datas]).reshape(-1, 3, 3)
        return {"sensordata": np.stack([d.sensordata for d in datas]), "xpos": xpos,
                "agent_pos": xpos[:, w.agent], "agent_mat": mat}

    def _obs(self, envs, world: dict[str, np.ndarray]) -> np.ndarray:
        sd = world["sensordata"]
        cols = []
        for how, adr, dim in self.sensors:
            if how == "raw":
                cols.append(sd[:, adr:adr + dim])
            elif how == "sincos":
                cols += [np.sin(sd[:, adr:adr + 1]), np.cos(sd[:, adr:adr + 1])]
            else:
                cols.append(_quat_mat(sd[:, adr:adr + 4]))
        pos, mat = world["agent_pos"], world["agent_mat"]
        cols.append(pseudo_lidar(self.goal[envs, None], pos, mat))
        if self.spec.level > 0:
            cols.append(pseudo_lidar(self.hazards[envs], pos, mat))
            cols.append(pseudo_lidar(world["xpos"][:, self.worlds.vases, :2], pos, mat))
        return np.concatenate(cols, axis=1)

    def _dist_goal(self, envs, world) -> np.ndarray:
        d = self.goal[envs] - world["agent_pos"][:, :2]
        return np.sqrt(np.sum(np.square(d), axis=-1))

    def _vase_cost(self) -> np.ndarray:
        """Level 2: a robot geom touching a vase, or a vase moving, costs."""
        w = self.worlds
        hit = np.zeros(self.num_envs, dtype=bool)
        dofs = w.vase_dof[:, None] + np.arange(3)
        for i, d in enumerate(w.datas):
            if d.ncon:
                g1, g2 = d.contact.geom1, d.contact.geom2
                touch = (w.geom_is_vase[g1] & w.geom_is_robot[g2]) | (w.geom_is_robot[g1] & w.geom_is_vase[g2])
                hit[i] = bool(np.any(touch))
            if not hit[i]:
                speed = np.sqrt(np.sum(np.square(d.qvel[dofs]), axis=-1))
                hit[i] = bool(np.any(speed >= VASE_SPEED))
        return hit

    # --- episodes ------------------------------------------------------------------------------
    def _start(self, envs: list[int], layouts: list[dict[str, Any]] | None = None) -> np.ndarray:
        """New episodes for ``envs`` (from new layouts, or the ones given); their first observations."""
        for k, i in enumerate(envs):
            layout = self.sampler.layout(i) if layouts is None else layouts[k]
            self.layouts[i] = layout
            self.worlds.place(i, layout)
            self.goal[i] = layout["goal"]
            self.hazards[i] = layout["hazards"]
        self.steps[envs] = 0
        world = self._gather(envs)
        self.last_dist[envs] = self._dist_goal(envs, world)
        return self._obs(envs, world)

    def _new_goal(self, i: int, world: dict[str, np.ndarray], row: int) -> bool:
        """Env ``i`` reached its goal: a new one, clear of where everything is now (False: none)."""
        others = [(*world["agent_pos"][row, :2], AGENT_KEEPOUT)]
        others += [(*xy, HAZARD_KEEPOUT) for xy in self.hazards[i]]
        others += [(*xy, VASE_KEEPOUT) for xy in world["xpos"][row, self.worlds.vases, :2]]
        goal = self.sampler.goal(i, others)
        if goal is None:
            return False
        self.goal[i] = goal
        self.worlds.move_goal(i, goal)
        return True

    def start_from(self, i: int, layout: dict[str, Any]) -> torch.Tensor:
        """Env ``i`` starts a new episode from ``layout`` (``safe_nav_layout.py``'s keys: xy of the
        robot, goal, hazards and vases and their rotations), e.g. one read from a reference env;
        its first observation. Later episodes draw their layouts as usual."""
        return self._tensor(self._start([i], [layout]))[0]

    def reset(self, seed: int | None = None) -> torch.Tensor:
        seeds = ([seed + i for i in range(self.num_envs)] if seed is not None
                 else [int(s) for s in np.random.randint(2**32, size=self.num_envs, dtype=np.int64)])
        self.sampler.seed(seeds)
        return self._tensor(self._start(list(range(self.num_envs))))

    def _tensor(self, x: np.ndarray, dtype=torch.float32) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x)).to(dtype=dtype, device=self.device)

    def step(self, action: torch.Tensor) -> Step:
        self.check_action(action)
        n, every = self.num_envs, slice(None)
        self.worlds.step(action.detach().cpu().numpy().astype(np.float64))
        self.sampler.pending += 1  # the reference's per-step draw
        world = self._gather(range(n))
        dist = self._dist_goal(every, world)
        reached = dist <= GOAL_SIZE
        reward = np.clip(self.last_dist - dist + reached * 1.0, -REWARD_CLIP, REWARD_CLIP)
        agent_xy = world["agent_pos"][:, None, :2]
        hazard_dist = np.sqrt(np.sum(np.square(self.hazards - agent_xy), axis=-1))
        cost = np.any(hazard_dist < HAZARD_SIZE, axis=-1)  # the reference's cost > 0, as an indicator
        if self.spec.vases_constrained:
            cost |= self._vase_cost()
        terminated = np.zeros(n, dtype=bool)
        self.last_dist = dist
        for i in np.flatnonzero(reached):
            if self._new_goal(i, world, i):
                self.last_dist[i] = math.sqrt(float(np.sum(np.square(self.goal[i] - world["agent_pos"][i, :2]))))
            else:
                terminated[i] = True
        self.steps += 1
        truncated = self.steps >= self.max_steps
        next_obs = self._obs(every, world)
        obs = next_obs
        done = np.flatnonzero(terminated | truncated)
        if len(done):
            obs = next_obs.copy()
            obs[done] = self._start(list(done))
        self.last = {"next_obs": next_obs, "reward": reward, "obs": obs}  # float64, for fidelity checks
        return Step(next_obs=self._tensor(next_obs), reward=self._tensor(reward).view(n, 1),
                    cost=self._tensor(cost).view(n, 1), terminated=self._tensor(terminated, torch.bool).view(n, 1),
                    truncated=self._tensor(truncated, torch.bool).view(n, 1), obs=self._tensor(obs))

    # --- resume --------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Each env's layout, goal and MuJoCo integration state, the step counters and the random
        streams: a fresh env restored from it continues bit for bit."""
        mj = self.worlds.mj
        spec = mj.mjtState.mjSTATE_INTEGRATION
        states = []
        for m, d in zip(self.worlds.models, self.worlds.datas):
            state = np.empty(mj.mj_stateSize(m, spec))
            mj.mj_getState(m, d, state, spec)
            states.append(state)
        return {"num_envs": self.num_envs, "task": self.task, "layouts": self.layouts, "goal": self.goal.copy(),
                "last_dist": self.last_dist.copy(), "steps": self.steps.copy(), "mujoco": states,
                "sampler": self.sampler.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["num_envs"] != self.num_envs or state["task"] != self.task:
            raise ValueError(f"env: saved state is for {state['num_envs']} envs of {state['task']}, "
                             f"this one has {self.num_envs} of {self.task}")
        mj = self.worlds.mj
        for i, (m, d) in enumerate(zip(self.worlds.models, self.worlds.datas)):
            self.layouts[i] = state["layouts"][i]
            self.worlds.place(i, self.layouts[i])
            self.hazards[i] = self.layouts[i]["hazards"]
            self.worlds.move_goal(i, state["goal"][i])
            mj.mj_setState(m, d, state["mujoco"][i], mj.mjtState.mjSTATE_INTEGRATION)
            mj.mj_forward(m, d)
        self.goal[:] = state["goal"]
        self.last_dist[:] = state["last_dist"]
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

    def env_id(self) -> str:
        return f"safe_nav/{self.task}"

    def check(self, run: Any) -> None:
        problem = task_problem(self.task)
        if problem:
            raise ConfigError(problem)
        require(self.max_steps <= EPISODE, "env.max_steps", f"in [0, {EPISODE}] (0: the task's limit)", self.max_steps)
        import importlib.util

        if importlib.util.find_spec("safety_gymnasium") is None or importlib.util.find_spec("mujoco") is None:
            raise ConfigError("env.name: env=safe_nav reads the robots' models from Safety-Gymnasium: "
                              "run `make setup-safety-gym`")

    def render_env(self):
        """The reference task drawing ``rgb_array`` frames (for video): its layouts and trajectories
        are this env's (docs/safe_nav.md), and it has the renderer's textures, lights and cameras."""
        from cmdp_rl.envs.safety_gym import make_task

        return make_task(f"Safety{self.task}-v0", self.max_steps, render_mode="rgb_array")


def make_safe_nav_vec_env(cfg: SafeNavEnvConfig, num_envs: int, device: str = "cpu") -> SafeNavVecEnv:
    return SafeNavVecEnv(cfg.task, num_envs, cfg.max_steps, device=device, threads=cfg.threads)


register("env", "safe_nav", SafeNavEnvConfig, make_safe_nav_vec_env)

__all__ = ["TASKS", "SafeNavEnvConfig", "SafeNavVecEnv", "make_safe_nav_vec_env", "pseudo_lidar", "task_problem"]
