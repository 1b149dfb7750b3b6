"""The Safety-Gymnasium tasks ``env=safety_gym`` offers with their registered episode limits, and why the
others are refused. Plain data (no Safety-Gymnasium import): the config check runs without the package."""

from __future__ import annotations

import re

ROBOTS = ("Point", "Car", "Racecar", "Doggo", "Ant")
NAVIGATION = ("Goal", "Button", "Push", "Circle")
LEVELS = (0, 1, 2)
VELOCITY_ROBOTS = ("HalfCheetah", "Hopper", "Swimmer", "Walker2d", "Ant", "Humanoid")


# id -> the episode limit Safety-Gymnasium registers it with (steps).
TASKS: dict[str, int] = {
    **{f"Safety{r}{f}{lv}-v0": 500 if f == "Circle" else 1000 for r in ROBOTS for f in NAVIGATION for lv in LEVELS},
    **{f"Safety{robot}Run0-v0": 500 for robot in ROBOTS},
    **{f"Safety{robot}Velocity-v{v}": 1000 for robot in VELOCITY_ROBOTS for v in (0, 1)},
}

ALLOWED = (
    f"Safety{{{','.join(ROBOTS)}}}{{{','.join(NAVIGATION)}}}{{0,1,2}}-v0, Safety{{{','.join(ROBOTS)}}}Run0-v0 "
    f"or Safety{{{','.join(VELOCITY_ROBOTS)}}}Velocity-v{{0,1}}"
)

# Registered ids we refuse: (pattern, why, the infix whose removal names an offered task); first match wins.
_REFUSED = (
    (r"^Safety\w+Vision-v\d+$", "observes camera images (our policies take flat vectors)", "Vision"),
    (r"^Safety\w+Debug-v\d+$", "is Safety-Gymnasium's keyboard-controlled debug variant", "Debug"),
    (r"^Safety\w+(Race|FadingEasy|FadingHard)\d-v\d+$", "is a vision-only task (camera images)", None),
    (r"^Safety\w+Gymnasium-v\d+$", "is Safety-Gymnasium's gymnasium-API copy of a task", "Gymnasium"),
    (
        r"^Safety\w+MultiGoal\d-v\d+$|^Safety\w+\d+x\d+\w*Velocity-v\d+$|^Safety\w*Multi\w*",
        "is a multi-agent task (needs gymnasium_robotics; not offered)",
        None,
    ),
)


def task_problem(task: str) -> str | None:
    """None if ``task`` is offered, else the one-line config error saying why not."""
    if task in TASKS:
        return None
    for pattern, why, infix in _REFUSED:
        if re.match(pattern, task):
            hint = task.replace(f"{infix}-", "-") if infix else None
            instead = f"; use {hint}" if hint in TASKS else ""
            return f"env.task must be an offered Safety-Gymnasium task, got {task!r}: it {why}{instead}"
    return f"env.task must be one of {ALLOWED}, got {task!r}"
