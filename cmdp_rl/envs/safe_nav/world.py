"""The MuJoCo side of ``env=safe_nav``: one world per task, compiled once, N copies stepped.

Safety-Gymnasium builds a navigation task's world as MJCF text (the robot's XML from its package,
plus a body per goal, hazard, vase, button, ...) and compiles it again at every reset, with the new layout
written into the text (about 0.8 s per compile here, a fifth of its run time;
``shared/notes/safety-gymnasium-facts.md``). Here the same world is compiled once, with the same
bodies in the same order, the same geoms and the same defaults (the robot's own XML, read from the
installed package at run time), so MuJoCo integrates it with the same arithmetic; each env gets a
copy of the compiled model, and a new layout moves bodies in that copy (``body_pos``, ``body_quat``,
``qpos0`` of free bodies; for the Button tasks' gremlins also what the compiler derives from
their places: mocap geom poses and weld poses), then re-derives what the compiler computes from the
initial pose (``mj_setConst``) and starts from a fresh state (``mj_resetData``), which is what a fresh compile and
a fresh ``MjData`` give. What only renders (textures, materials, lights, cameras) is left out: it
is most of the compile time and none of the physics.

The MJCF text is ``mjcf.py``'s, the task's objects and sizes ``spec.py``'s. A step copies what the
task logic reads (sensors, body positions, the robot's frame) out of each world as it steps it,
into arrays the env reads for all N worlds at once.
"""

from __future__ import annotations

import copy
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from cmdp_rl.envs.safe_nav.mjcf import rot_quat, world_xml
from cmdp_rl.envs.safe_nav.spec import (
    AGENT_KEEPOUT,
    BUTTON_SIZE,
    CIRCLE_Z,
    FRAMESKIP,
    GOAL_KEEPOUT,
    GREMLIN_SIZE,
    GREMLIN_TRAVEL,
    HAZARD_KEEPOUT,
    HAZARD_Z,
    PILLAR_HEIGHT,
    PUSH_BOX,
    ROBOTS,
    SIGWALL_Z,
    VASE_KEEPOUT,
    VASE_SINK,
    VASE_SIZE,
    NavSpec,
    nav_spec,
)


class NavWorlds:
    """N copies of one compiled world, each with its own layout, stepped in a tight loop (in
    ``threads`` threads, each stepping a share of the worlds: MuJoCo's step releases the GIL).

    ``place(i, layout)`` starts env ``i`` afresh from a layout (a dict of xy positions and
    rotations, ``safe_nav_layout.py``); ``step(ctrl)`` applies one env step (``FRAMESKIP`` physics
    steps, then a forward pass so that sensors and positions describe the new state) to every
    world.
    """

    proto = np.zeros(0)  # the task logic's arrays are numpy float64 (``arrays.py``)

    def __init__(self, spec: NavSpec, num_envs: int, threads: int = 1) -> None:
        import mujoco

        self.mj = mujoco
        self.spec = spec
        self.xml = world_xml(spec)
        base = mujoco.MjModel.from_xml_string(self.xml)
        self.models = [base] + [copy.copy(base) for _ in range(num_envs - 1)]
        self.datas = [mujoco.MjData(m) for m in self.models]
        body = lambda name: mujoco.mj_name2id(base, mujoco.mjtObj.mjOBJ_BODY, name)  # noqa: E731
        self.agent = body("agent")
        self.goal = body("goal")  # -1 where there is none (Circle)
        self.circle = body("circle")
        self.sigwalls = np.array([body(f"sigwall{i}") for i in range(spec.sigwalls)], dtype=np.int64)
        self.hazards = np.array([body(f"hazard{i}") for i in range(spec.hazards)], dtype=np.int64)
        self.vases = np.array([body(f"vase{i}") for i in range(spec.vases)], dtype=np.int64)
        self.buttons = np.array([body(f"button{i}") for i in range(spec.buttons)], dtype=np.int64)
        self.pillars = np.array([body(f"pillar{i}") for i in range(spec.pillars)], dtype=np.int64)
        self.push_box = body("push_box")  # -1 where there is none
        self.gremlins = np.array([body(f"gremlin{i}obj") for i in range(spec.gremlins)], dtype=np.int64)
        self.gremlin_mocaps = np.array([body(f"gremlin{i}mocap") for i in range(spec.gremlins)], dtype=np.int64)
        self.goal_z = spec.goal_size / 2 + 1e-2
        self.vase_dof = np.array([base.jnt_dofadr[base.body_jntadr[b]] for b in self.vases], dtype=np.int64)
        agent_joint = base.body_jntadr[self.agent]
        self.agent_free = base.jnt_type[agent_joint] == mujoco.mjtJoint.mjJNT_FREE
        self.agent_qpos = base.jnt_qposadr[agent_joint]
        self.agent_z = float(base.body_pos[self.agent][2])  # the robot body's height in its XML
        self.ctrl_low = base.actuator_ctrlrange[:, 0].copy()
        self.ctrl_high = base.actuator_ctrlrange[:, 1].copy()
        # Geoms that make a vase contact count (a vase with one of the robot's own geoms).
        names = [mujoco.mj_id2name(base, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in range(base.ngeom)]
        robot_bodies = {self.agent} | {b for b in range(base.nbody) if base.body_rootid[b] == self.agent}
        self.geom_is_robot = np.array(
            [base.geom_bodyid[g] in robot_bodies and names[g] != "floor" for g in range(base.ngeom)]
        )
        self.geom_is_vase = np.array([n.startswith("vase") for n in names])
        self.geom_button = np.array([int(n[6:]) if n.startswith("button") else -1 for n in names])
        self.geom_is_gremlin = np.array([n.startswith("gremlin") for n in names])
        self.geom_is_pillar = np.array([n.startswith("pillar") for n in names])
        self._targets: dict[float, tuple[np.ndarray, ...]] = {}  # gremlin targets by env-step start time
        # What the task logic reads of every world after a step, copied out by the stepping loop
        # itself (in each thread, for its share) rather than stacked from the N worlds afterwards:
        # the same values, one Python pass over the worlds instead of three.
        self.sensordata = np.zeros((num_envs, base.nsensordata))
        self.xpos = np.zeros((num_envs, base.nbody, 3))
        self.agent_mat = np.zeros((num_envs, 3, 3))
        self._agent_mat9 = self.agent_mat.reshape(num_envs, 9)  # a view: the row xmat is copied into
        threads = max(1, min(threads, num_envs))
        bounds = np.linspace(0, num_envs, threads + 1).astype(int)
        self.shares = [range(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:])]
        self.pool = ThreadPoolExecutor(threads) if threads > 1 else None

    @property
    def num_envs(self) -> int:
        return len(self.datas)

    def place(self, i: int, layout: dict) -> None:
        """Env ``i`` starts over from ``layout``: bodies moved, constants re-derived, state fresh."""
        mj, m, d = self.mj, self.models[i], self.datas[i]
        agent_quat = rot_quat(layout["agent_rot"])
        agent_pos = np.array([*layout["agent"], self.agent_z])
        m.body_pos[self.agent] = agent_pos
        m.body_quat[self.agent] = agent_quat
        if self.agent_free:
            a = self.agent_qpos
            m.qpos0[a : a + 3] = m.qpos_spring[a : a + 3] = agent_pos
            m.qpos0[a + 3 : a + 7] = m.qpos_spring[a + 3 : a + 7] = agent_quat
        if self.goal >= 0:
            m.body_pos[self.goal] = [*layout["goal"], self.goal_z]
            m.body_quat[self.goal] = rot_quat(layout["goal_rot"])
        if self.circle >= 0:  # the reference gives the circle and sigwalls fixed rotations
            m.body_pos[self.circle] = [*layout["circle"], CIRCLE_Z]
        for k, b in enumerate(self.sigwalls):
            m.body_pos[b] = [*layout["sigwalls"][k], SIGWALL_Z]
            m.body_quat[b] = rot_quat(math.pi / 2 if k >= 2 else 0.0)
        for k, b in enumerate(self.hazards):
            m.body_pos[b] = [*layout["hazards"][k], HAZARD_Z]
            m.body_quat[b] = rot_quat(layout["hazards_rot"][k])
        for k, b in enumerate(self.vases):
            self._place_free(m, b, layout["vases"][k], VASE_SIZE - VASE_SINK, layout["vases_rot"][k])
        for k, b in enumerate(self.pillars):
            m.body_pos[b] = [*layout["pillars"][k], PILLAR_HEIGHT]
            m.body_quat[b] = rot_quat(layout["pillars_rot"][k])
        if self.push_box >= 0:
            self._place_free(m, self.push_box, layout["push_box"], PUSH_BOX[self.spec.robot][0], layout["push_box_rot"])
        for k, b in enumerate(self.buttons):
            m.body_pos[b] = [*layout["buttons"][k], BUTTON_SIZE]
            m.body_quat[b] = rot_quat(layout["buttons_rot"][k])
        for k, (b, mocap) in enumerate(zip(self.gremlins, self.gremlin_mocaps)):
            pos, quat = self._place_free(m, b, layout["gremlins"][k], GREMLIN_SIZE, layout["gremlins_rot"][k])
            # what the compiler derives from the placed geom: the mocap body's inertial frame (its
            # one geom's) and the weld's relative pose (the box's pose, the mocap body at the origin)
            g = m.body_geomadr[mocap]
            m.geom_pos[g] = m.body_ipos[mocap] = m.eq_data[k, 3:6] = pos
            m.geom_quat[g] = m.body_iquat[mocap] = m.eq_data[k, 6:10] = quat
        mj.mj_setConst(m, d)
        mj.mj_resetData(m, d)
        mj.mj_forward(m, d)

    @staticmethod
    def _place_free(m, body: int, xy, z: float, rot: float) -> tuple[np.ndarray, np.ndarray]:
        """A free body's place: its body frame and its joint's initial (and spring) pose."""
        pos, quat = np.array([*xy, z]), rot_quat(rot)
        m.body_pos[body], m.body_quat[body] = pos, quat
        a = m.jnt_qposadr[m.body_jntadr[body]]
        m.qpos0[a : a + 3] = m.qpos_spring[a : a + 3] = pos
        m.qpos0[a + 3 : a + 7] = m.qpos_spring[a + 3 : a + 7] = quat
        return pos, quat

    def move_goal(self, i: int, xy: np.ndarray) -> None:
        """A new goal mid-episode: the goal has no contacts, so only its position changes."""
        self.models[i].body_pos[self.goal, :2] = xy

    def step(self, ctrl: np.ndarray) -> None:
        """One env step of every world: ``ctrl`` ``[N, nu]`` (clipped to the actuators' range); then
        :attr:`sensordata`, :attr:`xpos` and :attr:`agent_mat` hold every world's new state."""
        ctrl = np.clip(ctrl, self.ctrl_low, self.ctrl_high)
        if self.pool is None:
            self._step_share(self.shares[0], ctrl)
            return
        # Every share in a worker, the calling thread waiting: measured 1.7x faster than the
        # calling thread stepping one share itself (PointGoal1, 16 envs, 2026-11-28), which left
        # the two threads trading the GIL at every world.
        for future in [self.pool.submit(self._step_share, share, ctrl) for share in self.shares]:
            future.result()

    def read(self, envs) -> dict[str, np.ndarray]:
        """The state of worlds ``envs`` (after a placement or a restore: a step reads its own):
        copied into the gathered arrays, and returned as copies of their rows."""
        for i in envs:
            self._copy_out(i, self.datas[i])
        envs = list(envs)
        xpos = self.xpos[envs]
        return {
            "sensordata": self.sensordata[envs],
            "xpos": xpos,
            "agent_pos": xpos[:, self.agent],
            "agent_mat": self.agent_mat[envs],
        }

    def gathered(self) -> dict[str, np.ndarray]:
        """Every world's state after the last step: the gathered arrays themselves (views, which the
        next step overwrites)."""
        return {
            "sensordata": self.sensordata,
            "xpos": self.xpos,
            "agent_pos": self.xpos[:, self.agent],
            "agent_mat": self.agent_mat,
        }

    def _copy_out(self, i: int, d) -> None:
        self.sensordata[i] = d.sensordata
        self.xpos[i] = d.xpos
        self._agent_mat9[i] = d.xmat[self.agent]

    def contacts(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every world's contacts, concatenated: the env of each ``[C]`` and its two geoms ``[C]``,
        ``[C]`` (so that the task logic tests them in a few array operations, not a loop per env)."""
        pairs = [d.contact.geom for d in self.datas]
        env = np.repeat(np.arange(len(pairs)), [len(p) for p in pairs])
        pairs = np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=np.int32)
        return env, pairs[:, 0], pairs[:, 1]

    def touching(self, kind: np.ndarray) -> np.ndarray:
        """Per env: a robot geom touches a geom of ``kind`` (a flag per geom) ``[N]``."""
        env, g1, g2 = self.contacts()
        robot = self.geom_is_robot
        hit = np.zeros(self.num_envs, dtype=bool)
        hit[env[(kind[g1] & robot[g2]) | (robot[g1] & kind[g2])]] = True
        return hit

    def qvel(self, dofs: np.ndarray) -> np.ndarray:
        """Every world's joint velocities at ``dofs`` (an index array of any shape) ``[N, *dofs.shape]``."""
        return np.stack([d.qvel[dofs] for d in self.datas])

    def _step_share(self, envs: range, ctrl: np.ndarray) -> None:
        step, forward, copy_out = self.mj.mj_step, self.mj.mj_forward, self._copy_out
        models, datas = self.models, self.datas
        if len(self.gremlins):
            for i in envs:
                m, d = models[i], datas[i]
                d.ctrl[:] = ctrl[i]
                mocap = d.mocap_pos  # a view of the world's array (looked up once, not per physics step)
                for target in self._gremlin_targets(d.time, m.opt.timestep):
                    mocap[:] = target
                    step(m, d)
                forward(m, d)
                copy_out(i, d)
            return
        for i in envs:
            m, d = models[i], datas[i]
            d.ctrl[:] = ctrl[i]
            step(m, d, FRAMESKIP)  # FRAMESKIP steps in one call (one GIL release)
            forward(m, d)
            copy_out(i, d)

    def _gremlin_targets(self, time: float, timestep: float) -> tuple[np.ndarray, ...]:
        """Where every gremlin's mocap body goes before each of the ``FRAMESKIP`` physics steps of an
        env step starting at ``time``: the same point on a circle, with the reference's arithmetic
        (numpy's sin and cos of the float time, times 0.35), the times advanced as MuJoCo advances
        them (``time += timestep``, the same float addition). Every env runs through the same
        times (each starts at 0 and adds the same time step), so each env step's points are
        computed once and looked up after."""
        targets = self._targets.get(time)
        if targets is None:
            points, t = [], time
            for _ in range(FRAMESKIP):
                target = np.array([np.sin(t), np.cos(t)]) * GREMLIN_TRAVEL
                points.append(np.r_[target, [GREMLIN_SIZE]])
                t += timestep
            targets = self._targets[time] = tuple(points)
        return targets

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()


# The task spec's names, as they were when they lived here (the tests and lab code import them so).
__all__ = ["AGENT_KEEPOUT", "FRAMESKIP", "GOAL_KEEPOUT", "HAZARD_KEEPOUT", "ROBOTS", "VASE_KEEPOUT"]
__all__ += ["NavSpec", "NavWorlds", "nav_spec", "rot_quat"]
