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
# Button tasks: 4 buttons (spheres the robot can touch), a smaller goal (marking the goal button),
# and at levels 1, 2 gremlins: boxes welded to mocap bodies that circle (radius 0.35) round their
# places, moved before each physics step.
BUTTON_SIZE, BUTTON_KEEPOUT = 0.1, 0.2
BUTTON_GOAL_SIZE, BUTTON_GOAL_KEEPOUT = 0.2, 0.4
BUTTON_HAZARD_KEEPOUT = 0.18
GREMLIN_SIZE, GREMLIN_KEEPOUT, GREMLIN_TRAVEL, GREMLIN_DENSITY = 0.1, 0.4, 0.35, 0.001
# Push tasks: a box (four smaller boxes at its corners) to push onto the goal, wider hazards, and
# pillars (cylinders with contacts). The Car pushes a smaller, lighter box.
PUSH_BOX = {"point": (0.2, 0.001), "car": (0.125, 0.0005)}  # half-size (= keep-out), density
PUSH_HAZARD_SIZE, PUSH_HAZARD_KEEPOUT = 0.3, 0.4
PUSH_GOAL_KEEPOUT = 0.4
PILLAR_SIZE, PILLAR_HEIGHT, PILLAR_KEEPOUT = 0.2, 0.5, 0.3
FRAMESKIP = 10  # physics steps per env step (binomial(10, p=1): always 10)
ROBOTS = {"Point": "point", "Car": "car"}


@dataclass(frozen=True)
class NavSpec:
    """What a navigation task places: the robot, and counts of each object kind, in a square
    ``[-extent, extent]^2``; ``family`` is the task family (Goal, Circle, Button, Push)."""

    robot: str
    level: int
    extent: float
    hazards: int
    vases: int
    vases_constrained: bool
    family: str = "Goal"
    sigwalls: int = 0
    buttons: int = 0
    gremlins: int = 0
    goal_size: float = GOAL_SIZE
    hazard_size: float = HAZARD_SIZE
    pillars: int = 0
    pillars_constrained: bool = False
    push_box: bool = False


def nav_spec(task: str) -> NavSpec:
    """``PointGoal1`` -> its :class:`NavSpec` (KeyError for a task not offered here)."""
    for robot in ROBOTS:
        for level, (extent, hazards, vases, constrained) in enumerate(
            ((1.0, 0, 0, False), (1.5, 8, 1, False), (2.0, 10, 10, True))
        ):
            if task == f"{robot}Goal{level}":
                return NavSpec(ROBOTS[robot], level, extent, hazards, vases, constrained)
        for level, sigwalls in enumerate((0, 2, 4)):
            if task == f"{robot}Circle{level}":
                return NavSpec(ROBOTS[robot], level, 2.0, 0, 0, False, "Circle", sigwalls)
        for level, (extent, hazards, gremlins) in enumerate(((1.0, 0, 0), (1.5, 4, 4), (1.8, 8, 6))):
            if task == f"{robot}Button{level}":
                return NavSpec(
                    ROBOTS[robot],
                    level,
                    extent,
                    hazards,
                    0,
                    False,
                    "Button",
                    buttons=4,
                    gremlins=gremlins,
                    goal_size=BUTTON_GOAL_SIZE,
                )
        for level, (extent, hazards, pillars) in enumerate(((1.0, 0, 0), (1.5, 2, 1), (2.0, 4, 4))):
            if task == f"{robot}Push{level}":
                return NavSpec(
                    ROBOTS[robot],
                    level,
                    extent,
                    hazards,
                    0,
                    False,
                    "Push",
                    hazard_size=PUSH_HAZARD_SIZE,
                    pillars=pillars,
                    pillars_constrained=level == 2,
                    push_box=True,
                )
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
    """The task's MJCF: the robot's XML with the floor resized as Safety-Gymnasium does, then, in
    its body order, the free bodies (box, vases, gremlins), the gremlins' mocap bodies (and their
    welds), and the fixed ones (circle and sigwalls; or buttons, goal, hazards, pillars).
    Positions are placeholders; layouts are set on the compiled model."""
    root = ET.parse(os.path.join(package_dir(), "assets", "xmls", f"{spec.robot}.xml")).getroot()
    worldbody = root.find("worldbody")
    for geom in worldbody.findall("geom"):
        if geom.get("name") == "floor":
            geom.set("size", "3.5 3.5 0.1")
    if spec.push_box:
        size, density = PUSH_BOX[spec.robot]
        body = ET.SubElement(worldbody, "body", name="push_box", pos="0 0 0", quat="1 0 0 0")
        ET.SubElement(body, "freejoint", name="push_box")
        ET.SubElement(
            body, "geom", name="push_box", type="box", size=_fmt([size] * 3), density=repr(density), group="1"
        )
        for k, (sx, sy) in enumerate(((1, 1), (-1, 1), (1, -1), (-1, -1))):
            ET.SubElement(
                body,
                "geom",
                name=f"col{k + 1}",
                type="box",
                size=_fmt([size / 2, size / 2, size]),
                density=repr(density),
                group="1",
                pos=_fmt([sx * size, sy * size, 0.0]),
            )
    frees = [(f"vase{i}", VASE_SIZE, VASE_DENSITY, "4") for i in range(spec.vases)]
    frees += [(f"gremlin{i}obj", GREMLIN_SIZE, GREMLIN_DENSITY, "5") for i in range(spec.gremlins)]
    for name, size, density, group in frees:
        body = ET.SubElement(worldbody, "body", name=name, pos="0 0 0", quat="1 0 0 0")
        ET.SubElement(body, "freejoint", name=name)
        ET.SubElement(body, "geom", name=name, type="box", size=_fmt([size] * 3), density=repr(density), group=group)
    if spec.gremlins:
        equality = root.find("equality")
        equality = ET.SubElement(root, "equality") if equality is None else equality
    for i in range(spec.gremlins):
        # The mocap body stays at the origin; its geom sits at the gremlin's place (placeholder
        # pose off the body frame, so that the compiler does not mark the two frames as one).
        body = ET.SubElement(worldbody, "body", name=f"gremlin{i}mocap", mocap="true")
        ET.SubElement(
            body,
            "geom",
            name=f"gremlin{i}mocap",
            type="box",
            size=_fmt([GREMLIN_SIZE] * 3),
            pos="0.5 0.5 0.1",
            quat=_fmt(rot_quat(1.0)),
            contype="0",
            conaffinity="0",
            group="5",
        )
        ET.SubElement(
            equality,
            "weld",
            name=f"gremlin{i}mocap",
            body1=f"gremlin{i}mocap",
            body2=f"gremlin{i}obj",
            solref=".02 1.5",
        )
    # (name, type, size, group, has contacts)
    if spec.family == "Circle":
        statics = [("circle", "cylinder", [CIRCLE_RADIUS, 1e-2], "6", False)]
        statics += [(f"sigwall{i}", "box", SIGWALL_SIZE, "10", False) for i in range(spec.sigwalls)]
    else:
        statics = [(f"button{i}", "sphere", [BUTTON_SIZE] * 3, "1", True) for i in range(spec.buttons)]
        statics += [("goal", "cylinder", [spec.goal_size, spec.goal_size / 2], "9", False)]
        statics += [(f"hazard{i}", "cylinder", [spec.hazard_size, 1e-2], "3", False) for i in range(spec.hazards)]
        statics += [(f"pillar{i}", "cylinder", [PILLAR_SIZE, PILLAR_HEIGHT], "2", True) for i in range(spec.pillars)]
    for name, kind, size, group, touch in statics:
        body = ET.SubElement(worldbody, "body", name=name, pos="0 0 0", quat="1 0 0 0")
        ET.SubElement(
            body,
            "geom",
            name=name,
            type=kind,
            size=_fmt(size),
            group=group,
            contype="1" if touch else "0",
            conaffinity="1" if touch else "0",
        )
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
        self._targets: dict[float, np.ndarray] = {}  # gremlin targets by simulation time
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
        if len(self.gremlins):
            for i in envs:
                m, d = models[i], datas[i]
                d.ctrl[:] = ctrl[i]
                for _ in range(FRAMESKIP):
                    d.mocap_pos[:] = self._gremlin_target(float(d.time))
                    step(m, d)
                forward(m, d)
            return
        for i in envs:
            m, d = models[i], datas[i]
            d.ctrl[:] = ctrl[i]
            step(m, d, FRAMESKIP)  # FRAMESKIP steps in one call (one GIL release)
            forward(m, d)

    def _gremlin_target(self, time: float) -> np.ndarray:
        """Where every gremlin's mocap body goes before a physics step at ``time``: the same point
        on a circle, with the reference's arithmetic (numpy's sin and cos of the float time, times
        0.35). Every env runs through the same times (each starts at 0 and adds the same time
        step), so each point is computed once and looked up after."""
        pos = self._targets.get(time)
        if pos is None:
            target = np.array([np.sin(time), np.cos(time)]) * GREMLIN_TRAVEL
            pos = self._targets[time] = np.r_[target, [GREMLIN_SIZE]]
        return pos

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()
