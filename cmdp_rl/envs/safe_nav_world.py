"""The MuJoCo side of ``env=safe_nav``: one world per task, compiled once, N copies stepped.

Safety-Gymnasium builds a navigation task's world as MJCF text (the robot's XML from its package,
plus a body per goal, hazard and vase) and compiles it again at every reset, with the new layout
written into the text (about 0.8 s per compile here, a fifth of its run time;
``shared/notes/safety-gymnasium-facts.md``). Here the same world is compiled once, with the same
bodies in the same order, the same geoms and the same defaults (the robot's own XML, read from the
installed package at run time), so MuJoCo integrates it with the same arithmetic; each env gets a
copy of the compiled model, and a new layout moves bodies in that copy (``body_pos``, ``body_quat``,
``qpos0`` of free bodies), then re-derives what the compiler computes from the initial pose
(``mj_setConst``) and starts from a fresh state (``mj_resetData``), which is what a fresh compile and
a fresh ``MjData`` give. What only renders (textures, materials, lights, cameras) is left out: it
is most of the compile time and none of the physics.
"""

from __future__ import annotations

import copy
import importlib.util
import math
import os
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

# Object sizes and placements of Safety-Gymnasium 1.0.0's Goal tasks (facts read from its asset
# and task definitions, not its code): radius, keep-out radius, body height.
GOAL_SIZE, GOAL_KEEPOUT, GOAL_Z = 0.3, 0.305, 0.3 / 2 + 1e-2
HAZARD_SIZE, HAZARD_KEEPOUT, HAZARD_Z = 0.2, 0.18, 2e-2
VASE_SIZE, VASE_KEEPOUT, VASE_DENSITY, VASE_SINK = 0.1, 0.15, 0.001, 4e-5
AGENT_KEEPOUT = 0.4
# Circle tasks: the circle (radius, never touched: it only shapes the reward and the lidar) and the
# sigwalls, boundaries without contacts at x = +-1.125 (and y = +-1.125 at level 2), placed, as
# the reference places every fixed object, by a draw within 1e-9 of their location.
CIRCLE_RADIUS, CIRCLE_Z = 1.5, 1e-2
SIGWALL_AT, SIGWALL_SIZE, SIGWALL_Z = 1.125, (0.05, 3.5, 0.3), 0.25
FRAMESKIP = 10  # physics steps per env step (binomial(10, p=1): always 10)
ROBOTS = {"Point": "point", "Car": "car"}


@dataclass(frozen=True)
class NavSpec:
    """What a navigation task places: the robot, and counts of each object kind, in a square
    ``[-extent, extent]^2``; ``family`` is the task family (Goal, Circle)."""

    robot: str
    level: int
    extent: float
    hazards: int
    vases: int
    vases_constrained: bool
    family: str = "Goal"
    sigwalls: int = 0


def nav_spec(task: str) -> NavSpec:
    """``PointGoal1`` -> its :class:`NavSpec` (KeyError for a task not offered here)."""
    for robot in ROBOTS:
        for level, (extent, hazards, vases, constrained) in enumerate(
                ((1.0, 0, 0, False), (1.5, 8, 1, False), (2.0, 10, 10, True))):
            if task == f"{robot}Goal{level}":
                return NavSpec(ROBOTS[robot], level, extent, hazards, vases, constrained)
        for level, sigwalls in enumerate((0, 2, 4)):
            if task == f"{robot}Circle{level}":
                return NavSpec(ROBOTS[robot], level, 2.0, 0, 0, False, "Circle", sigwalls)
    raise KeyError(task)


def package_dir() -> str:
    """The installed Safety-Gymnasium package's folder (found, not imported: its import needs our
    compatibility layer, and only its data files are read here)."""
    spec = importlib.util.find_spec("safety_gymnasium")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("env=safe_nav reads the robots' models from Safety-Gymnasium: run `make setup-safety-gym`")
    return list(spec.submodule_search_locations)[0]


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in np.atleast_1d(values))


def world_xml(spec: NavSpec) -> str:
    """The task's MJCF: the robot's XML with the floor resized as Safety-Gymnasium does, then the
    vases, the goal and the hazards (its body order). Positions are placeholders; layouts are set
    on the compiled model."""
    root = ET.parse(os.path.join(package_dir(), "assets", "xmls", f"{spec.robot}.xml")).getroot()
    worldbody = root.find("worldbody")
    for geom in worldbody.findall("geom"):
        if geom.get("name") == "floor":
            geom.set("size", "3.5 3.5 0.1")
    for i in range(spec.vases):
        body = ET.SubElement(worldbody, "body", name=f"vase{i}", pos="0 0 0", quat="1 0 0 0")
        ET.SubElement(body, "freejoint", name=f"vase{i}")
        ET.SubElement(body, "geom", name=f"vase{i}", type="box", size=_fmt([VASE_SIZE] * 3),
                      density=repr(VASE_DENSITY), group="4")
    if spec.family == "Circle":
        statics = [("circle", "cylinder", [CIRCLE_RADIUS, 1e-2], "6")]
        statics += [(f"sigwall{i}", "box", SIGWALL_SIZE, "10") for i in range(spec.sigwalls)]
    else:
        statics = [("goal", "cylinder", [GOAL_SIZE, GOAL_SIZE / 2], "9")]
        statics += [(f"hazard{i}", "cylinder", [HAZARD_SIZE, 1e-2], "3") for i in range(spec.hazards)]
    for name, kind, size, group in statics:
        body = ET.SubElement(worldbody, "body", name=name, pos="0 0 0", quat="1 0 0 0")
        ET.SubElement(body, "geom", name=name, type=kind, size=_fmt(size), group=group,
                      contype="0", conaffinity="0")
    return ET.tostring(root, encoding="unicode")


def rot_quat(theta: float) -> np.ndarray:
    """A rotation by ``theta`` about z as the compiler stores it: (cos, 0, 0, sin) of the half
    angle, normalised by MuJoCo's own rule (left as is when within 1e-15 of unit length, as the
    compiler leaves it: a plain division would differ from the compiled model in the last bit)."""
    import mujoco

    quat = np.array([math.cos(theta / 2), 0.0, 0.0, math.sin(theta / 2)])
    mujoco.mju_normalize4(quat)
    return quat


class NavWorlds:
    """N copies of one compiled world, each with its own layout, stepped in a tight loop (in
    ``threads`` threads, each stepping a share of the worlds: MuJoCo's step releases the GIL).

    ``place(i, layout)`` starts env ``i`` afresh from a layout (a dict of xy positions and
    rotations, ``safe_nav_layout.py``); ``step(ctrl)`` applies one env step (``FRAMESKIP`` physics
    steps, then a forward pass so that sensors and positions describe the new state) to every
    world.
    """

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
        self.vase_qpos = np.array([base.jnt_qposadr[base.body_jntadr[b]] for b in self.vases], dtype=np.int64)
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
        self.geom_is_robot = np.array([base.geom_bodyid[g] in robot_bodies and names[g] != "floor"
                                       for g in range(base.ngeom)])
        self.geom_is_vase = np.array([n.startswith("vase") for n in names])
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
            m.qpos0[a:a + 3] = m.qpos_spring[a:a + 3] = agent_pos
            m.qpos0[a + 3:a + 7] = m.qpos_spring[a + 3:a + 7] = agent_quat
        if self.goal >= 0:
            m.body_pos[self.goal] = [*layout["goal"], GOAL_Z]
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
            pos = np.array([*layout["vases"][k], VASE_SIZE - VASE_SINK])
            quat = rot_quat(layout["vases_rot"][k])
            m.body_pos[b] = pos
            m.body_quat[b] = quat
            a = self.vase_qpos[k]
            m.qpos0[a:a + 3] = m.qpos_spring[a:a + 3] = pos
            m.qpos0[a + 3:a + 7] = m.qpos_spring[a + 3:a + 7] = quat
        mj.mj_setConst(m, d)
        mj.mj_resetData(m, d)
        mj.mj_forward(m, d)

    def move_goal(self, i: int, xy: np.ndarray) -> None:
        """A new goal mid-episode: the goal has no contacts, so only its position changes."""
        self.models[i].body_pos[self.goal, :2] = xy

    def step(self, ctrl: np.ndarray) -> None:
        """One env step of every world: ``ctrl`` ``[N, nu]`` (clipped to the actuators' range)."""
        ctrl = np.clip(ctrl, self.ctrl_low, self.ctrl_high)
        if self.pool is None:
            self._step_share(self.shares[0], ctrl)
        else:
            for future in [self.pool.submit(self._step_share, share, ctrl) for share in self.shares]:
                future.result()

    def _step_share(self, envs: range, ctrl: np.ndarray) -> None:
        step, forward = self.mj.mj_step, self.mj.mj_forward
        models, datas = self.models, self.datas
        for i in envs:
            m, d = models[i], datas[i]
            d.ctrl[:] = ctrl[i]
            step(m, d, FRAMESKIP)  # FRAMESKIP steps in one call (one GIL release)
            forward(m, d)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()
