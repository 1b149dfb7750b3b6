"""What a navigation task of ``env=safe_nav`` places: Safety-Gymnasium 1.0.0's object sizes and
keep-outs, and each task's :class:`NavSpec` (robot, level, counts of each object kind)."""

from __future__ import annotations

from dataclasses import dataclass

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
