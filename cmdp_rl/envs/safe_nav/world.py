"""The MuJoCo side of ``env=safe_nav``: the task's world compiled once (``mjcf.py``), N copies stepped in
one loop; a layout moves bodies in a copy and re-derives what the compiler would (docs/safe_nav.md)."""

from __future__ import annotations

import copy
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from cmdp_rl.envs.safe_nav import spec as sg  # Safety-Gymnasium 1.0.0's object sizes and keep-outs
from cmdp_rl.envs.safe_nav.mjcf import rot_quat, world_xml
from cmdp_rl.envs.safe_nav.spec import NavSpec


class NavWorlds:
    """N copies of one compiled world, stepped in one loop (or ``threads``: MuJoCo's step releases the GIL)."""

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
        self.agent_free = base.jnt_type[base.body_jntadr[self.agent]] == mujoco.mjtJoint.mjJNT_FREE
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
        # What the task logic reads of every world, copied out by the stepping loop itself (one pass).
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
        if self.agent_free:
            self._place_free(m, self.agent, layout["agent"], self.agent_z, layout["agent_rot"])
        else:
            m.body_pos[self.agent] = [*layout["agent"], self.agent_z]
            m.body_quat[self.agent] = rot_quat(layout["agent_rot"])
        if self.goal >= 0:
            m.body_pos[self.goal] = [*layout["goal"], self.goal_z]
            m.body_quat[self.goal] = rot_quat(layout["goal_rot"])
        if self.circle >= 0:  # the reference gives the circle and sigwalls fixed rotations
            m.body_pos[self.circle] = [*layout["circle"], sg.CIRCLE_Z]
        for k, b in enumerate(self.sigwalls):
            m.body_pos[b] = [*layout["sigwalls"][k], sg.SIGWALL_Z]
            m.body_quat[b] = rot_quat(math.pi / 2 if k >= 2 else 0.0)
        for bodies, kind, z in ((self.hazards, "hazards", sg.HAZARD_Z), (self.pillars, "pillars", sg.PILLAR_HEIGHT)):
            for k, b in enumerate(bodies):
                m.body_pos[b] = [*layout[kind][k], z]
                m.body_quat[b] = rot_quat(layout[f"{kind}_rot"][k])
        for k, b in enumerate(self.buttons):
            m.body_pos[b] = [*layout["buttons"][k], sg.BUTTON_SIZE]
            m.body_quat[b] = rot_quat(layout["buttons_rot"][k])
        for k, b in enumerate(self.vases):
            self._place_free(m, b, layout["vases"][k], sg.VASE_SIZE - sg.VASE_SINK, layout["vases_rot"][k])
        if self.push_box >= 0:
            self._place_free(
                m, self.push_box, layout["push_box"], sg.PUSH_BOX[self.spec.robot][0], layout["push_box_rot"]
            )
        for k, (b, mocap) in enumerate(zip(self.gremlins, self.gremlin_mocaps)):
            pos, quat = self._place_free(m, b, layout["gremlins"][k], sg.GREMLIN_SIZE, layout["gremlins_rot"][k])
            # what the compiler derives from the placed geom: the mocap body's inertial frame, the weld's pose
            g = m.body_geomadr[mocap]
            m.geom_pos[g] = m.body_ipos[mocap] = m.eq_data[k, 3:6] = pos
            m.geom_quat[g] = m.body_iquat[mocap] = m.eq_data[k, 6:10] = quat
        mj.mj_setConst(m, d)
        mj.mj_resetData(m, d)
        mj.mj_forward(m, d)
        self._copy_out(i, d)

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
        """One env step of every world: ``ctrl`` ``[N, nu]``, clipped to the actuators' range."""
        ctrl = np.clip(ctrl, self.ctrl_low, self.ctrl_high)
        if self.pool is None:
            self._step_share(self.shares[0], ctrl)
            return
        # Every share in a worker, the calling thread waiting (docs/throughput.md says why).
        for future in [self.pool.submit(self._step_share, share, ctrl) for share in self.shares]:
            future.result()

    def gather(self, envs) -> dict[str, np.ndarray]:
        """What the task logic reads of worlds ``envs``: copies of their rows, or with ``slice(None)``
        views of every world's (which the next step overwrites)."""
        xpos = self.xpos[envs]
        return {
            "sensordata": self.sensordata[envs],
            "xpos": xpos,
            "agent_pos": xpos[:, self.agent],
            "agent_mat": self.agent_mat[envs],
        }

    def get_states(self) -> list[np.ndarray]:
        """Every world's MuJoCo integration state."""
        mj, kind = self.mj, self.mj.mjtState.mjSTATE_INTEGRATION
        states = [np.empty(mj.mj_stateSize(m, kind)) for m in self.models]
        for m, d, state in zip(self.models, self.datas, states):
            mj.mj_getState(m, d, state, kind)
        return states

    def set_states(self, states) -> None:
        """Every world continues from ``states`` (after its layout was placed)."""
        mj = self.mj
        for i, (m, d, saved) in enumerate(zip(self.models, self.datas, states)):
            mj.mj_setState(m, d, saved, mj.mjtState.mjSTATE_INTEGRATION)
            mj.mj_forward(m, d)
            self._copy_out(i, d)

    def _copy_out(self, i: int, d) -> None:
        self.sensordata[i] = d.sensordata
        self.xpos[i] = d.xpos
        self._agent_mat9[i] = d.xmat[self.agent]

    def contacts(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every world's contacts, concatenated: the env of each ``[C]`` and its two geoms ``[C]``, ``[C]``."""
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
            step(m, d, sg.FRAMESKIP)  # FRAMESKIP steps in one call (one GIL release)
            forward(m, d)
            copy_out(i, d)

    def _gremlin_targets(self, time: float, timestep: float) -> tuple[np.ndarray, ...]:
        """Where every gremlin's mocap body goes before each physics step of an env step starting at
        ``time``, with the reference's arithmetic, the times advanced as MuJoCo advances them. Every env
        runs through the same times, so each env step's points are computed once and looked up after."""
        targets = self._targets.get(time)
        if targets is None:
            points, t = [], time
            for _ in range(sg.FRAMESKIP):
                target = np.array([np.sin(t), np.cos(t)]) * sg.GREMLIN_TRAVEL
                points.append(np.r_[target, [sg.GREMLIN_SIZE]])
                t += timestep
            targets = self._targets[time] = tuple(points)
        return targets

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()
