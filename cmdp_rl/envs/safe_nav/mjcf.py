"""A navigation task's world as MJCF text (the robot's XML from the installed Safety-Gymnasium, then
the objects in the reference's body order, with its geoms), and rotations as MuJoCo's compiler stores them."""

from __future__ import annotations

import importlib.util
import math
import os
import xml.etree.ElementTree as ET

import numpy as np

from cmdp_rl.envs.safe_nav import spec as sg  # Safety-Gymnasium 1.0.0's object sizes and keep-outs
from cmdp_rl.envs.safe_nav.spec import NavSpec

CORNERS = ((1, 1), (-1, 1), (1, -1), (-1, -1))  # the push box's four smaller boxes


def package_dir() -> str:
    """The installed Safety-Gymnasium package's folder (found, not imported: only its data files are read)."""
    spec = importlib.util.find_spec("safety_gymnasium")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("env=safe_nav reads the robots' models from Safety-Gymnasium: run `make setup-safety-gym`")
    return list(spec.submodule_search_locations)[0]


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in np.atleast_1d(values))


def world_xml(spec: NavSpec) -> str:
    """The task's MJCF, in the reference's body order: free bodies, the gremlins' mocap bodies (and
    welds), fixed bodies. Positions are placeholders: layouts are set on the compiled model."""
    root = ET.parse(os.path.join(package_dir(), "assets", "xmls", f"{spec.robot}.xml")).getroot()
    worldbody = root.find("worldbody")
    for geom in worldbody.findall("geom"):
        if geom.get("name") == "floor":
            geom.set("size", "3.5 3.5 0.1")
    # free bodies: (name, its box geoms (name, half sizes, offset or None), density, group)
    frees = []
    if spec.push_box:
        size, density = sg.PUSH_BOX[spec.robot]
        corners = [
            (f"col{k + 1}", [size / 2, size / 2, size], [x * size, y * size, 0.0]) for k, (x, y) in enumerate(CORNERS)
        ]
        frees.append(("push_box", [("push_box", [size] * 3, None), *corners], density, "1"))
    frees += [(f"vase{i}", [(f"vase{i}", [sg.VASE_SIZE] * 3, None)], sg.VASE_DENSITY, "4") for i in range(spec.vases)]
    for i in range(spec.gremlins):
        frees.append((f"gremlin{i}obj", [(f"gremlin{i}obj", [sg.GREMLIN_SIZE] * 3, None)], sg.GREMLIN_DENSITY, "5"))
    for name, geoms, density, group in frees:
        body = ET.SubElement(worldbody, "body", name=name, pos="0 0 0", quat="1 0 0 0")
        ET.SubElement(body, "freejoint", name=name)
        for geom, size, pos in geoms:
            box = dict(name=geom, type="box", size=_fmt(size), density=repr(density), group=group)
            ET.SubElement(body, "geom", box if pos is None else {**box, "pos": _fmt(pos)})
    if spec.gremlins:
        equality = root.find("equality")
        equality = ET.SubElement(root, "equality") if equality is None else equality
    for i in range(spec.gremlins):
        # The mocap body stays at the origin, its geom at the gremlin's place (a placeholder pose off the body
        # frame, so that the compiler does not merge the two frames).
        name = f"gremlin{i}mocap"
        body = ET.SubElement(worldbody, "body", name=name, mocap="true")
        box = dict(name=name, type="box", size=_fmt([sg.GREMLIN_SIZE] * 3), pos="0.5 0.5 0.1", quat=_fmt(rot_quat(1.0)))
        ET.SubElement(body, "geom", box, contype="0", conaffinity="0", group="5")
        ET.SubElement(equality, "weld", name=name, body1=name, body2=f"gremlin{i}obj", solref=".02 1.5")
    # (name, type, size, group, has contacts)
    if spec.family == "Circle":
        statics = [("circle", "cylinder", [sg.CIRCLE_RADIUS, 1e-2], "6", False)]
        statics += [(f"sigwall{i}", "box", sg.SIGWALL_SIZE, "10", False) for i in range(spec.sigwalls)]
    else:
        statics = [(f"button{i}", "sphere", [sg.BUTTON_SIZE] * 3, "1", True) for i in range(spec.buttons)]
        statics += [("goal", "cylinder", [spec.goal_size, spec.goal_size / 2], "9", False)]
        statics += [(f"hazard{i}", "cylinder", [spec.hazard_size, 1e-2], "3", False) for i in range(spec.hazards)]
        statics += [
            (f"pillar{i}", "cylinder", [sg.PILLAR_SIZE, sg.PILLAR_HEIGHT], "2", True) for i in range(spec.pillars)
        ]
    for name, kind, size, group, touch in statics:
        body = ET.SubElement(worldbody, "body", name=name, pos="0 0 0", quat="1 0 0 0")
        contacts = "1" if touch else "0"
        ET.SubElement(
            body, "geom", name=name, type=kind, size=_fmt(size), group=group, contype=contacts, conaffinity=contacts
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
