"""Layouts of ``env=safe_nav``, drawn as Safety-Gymnasium draws them (docs/safe_nav.md, "How it works"):
one ``RandomState`` per env seeded ``seed + i`` as gymnasium seeds a vector env, making the reference's
draws in its order, so a seed gives the reference's layouts (tested)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cmdp_rl.envs.safe_nav import spec as sg  # Safety-Gymnasium 1.0.0's object sizes and keep-outs
from cmdp_rl.envs.safe_nav.spec import NavSpec

LAYOUT_TRIES = 10_000  # whole layouts, and goal places mid-episode
OBJECT_TRIES = 100  # places per object within one layout
FIXED_SLACK = 1e-9  # a fixed location is drawn within this of its place (as the reference does)
SINGLE = ("agent", "goal", "circle", "push_box")  # kinds with one object: a layout holds its xy and rotation plainly
Box = tuple[float, float, float, float]  # xmin, ymin, xmax, ymax


def _fixed(x: float, y: float, keepout: float) -> Box:
    k = keepout + FIXED_SLACK
    return (x - k, y - k, x + k, y + k)


def placements(spec: NavSpec) -> list[tuple[str, float, Box | None]]:
    """The objects a layout places, in the reference's order: (kind, keep-out, box drawn in or None: the square)."""
    if spec.family == "Circle":
        walls = [(sg.SIGWALL_AT, 0.0), (-sg.SIGWALL_AT, 0.0), (0.0, sg.SIGWALL_AT), (0.0, -sg.SIGWALL_AT)]
        return [("agent", 0.0, (-0.8, -0.8, 0.8, 0.8)), ("circle", 0.0, _fixed(0.0, 0.0, 0.0))] + [
            ("sigwalls", 0.0, _fixed(*walls[k], 0.0)) for k in range(spec.sigwalls)
        ]
    if spec.family == "Button":
        return (
            [("agent", sg.AGENT_KEEPOUT, None)]
            + [("buttons", sg.BUTTON_KEEPOUT, None)] * spec.buttons
            + [("goal", sg.BUTTON_GOAL_KEEPOUT, None)]
            + [("hazards", sg.BUTTON_HAZARD_KEEPOUT, None)] * spec.hazards
            + [("gremlins", sg.GREMLIN_KEEPOUT, None)] * spec.gremlins
        )
    if spec.family == "Push":
        return (
            [("agent", sg.AGENT_KEEPOUT, None), ("goal", sg.PUSH_GOAL_KEEPOUT, None)]
            + [("hazards", sg.PUSH_HAZARD_KEEPOUT, None)] * spec.hazards
            + [("pillars", sg.PILLAR_KEEPOUT, None)] * spec.pillars
            + [("push_box", sg.PUSH_BOX[spec.robot][0], None)]
        )
    return (
        [("agent", sg.AGENT_KEEPOUT, None), ("goal", sg.GOAL_KEEPOUT, None)]
        + [("hazards", sg.HAZARD_KEEPOUT, None)] * spec.hazards
        + [("vases", sg.VASE_KEEPOUT, None)] * spec.vases
    )


class LayoutError(RuntimeError):
    """No layout found within the tries (Safety-Gymnasium raises its ResamplingError)."""


def _clear(xy: tuple[float, float], keepout: float, placed: list[tuple[float, float, float]]) -> bool:
    x, y = xy
    for ox, oy, other_keepout in placed:
        dx, dy = x - ox, y - oy
        if math.sqrt(dx * dx + dy * dy) < other_keepout + 0.0 + keepout:  # + 0.0: its placement margin
            return False
    return True


class LayoutSampler:
    """Layouts for one task; ``rngs[i]`` is env ``i``'s stream, ``pending[i]`` the per-step draws it has not
    yet made (made, and discarded, before its next real draw: in step with the reference at no cost)."""

    def __init__(self, spec: NavSpec, num_envs: int) -> None:
        self.spec = spec
        self.objects = placements(spec)
        self.kinds = list(dict.fromkeys([k for k, _, _ in self.objects] + ["hazards", "vases", "pillars"]))
        self.rngs = [np.random.RandomState(0) for _ in range(num_envs)]
        self.pending = np.zeros(num_envs, dtype=np.int64)

    def seed(self, seeds: list[int]) -> None:
        self.rngs = [np.random.RandomState(s) for s in seeds]
        self.pending[:] = 0

    def _rng(self, i: int) -> np.random.RandomState:
        rng = self.rngs[i]
        if self.pending[i]:
            rng.random_sample(int(self.pending[i]))  # a binomial(n, 1.0) draw consumes one double
            self.pending[i] = 0
        return rng

    def _draw(self, rng: np.random.RandomState, keepout: float, box: Box | None = None) -> tuple[float, float]:
        e = self.spec.extent
        xmin, ymin, xmax, ymax = box if box is not None else (-e, -e, e, e)
        return rng.uniform(xmin + keepout, xmax - keepout), rng.uniform(ymin + keepout, ymax - keepout)

    def layout(self, i: int) -> dict[str, Any]:
        """A new layout for env ``i``: each kind's xy (``[count, 2]`` where several) and rotation (``<kind>_rot``)."""
        rng = self._rng(i)
        for _ in range(LAYOUT_TRIES):
            placed: list[tuple[float, float, float]] = []
            for _, keepout, box in self.objects:
                for _ in range(OBJECT_TRIES):
                    xy = self._draw(rng, keepout, box)
                    if _clear(xy, keepout, placed):
                        placed.append((*xy, keepout))
                        break
                else:
                    break
            if len(placed) == len(self.objects):
                break
        else:
            raise LayoutError(f"safe_nav: no layout found in {LAYOUT_TRIES} tries")
        xy = np.array([p[:2] for p in placed])
        rots = [rng.uniform(0, 2 * np.pi) for _ in self.objects]
        layout: dict[str, Any] = {}
        for kind in self.kinds:
            at = [k for k, (name, _, _) in enumerate(self.objects) if name == kind]
            if kind in SINGLE:
                layout[kind], layout[f"{kind}_rot"] = xy[at[0]], rots[at[0]]
            else:
                layout[kind], layout[f"{kind}_rot"] = xy[at].reshape(-1, 2), [rots[k] for k in at]
        if self.spec.family not in ("Goal", "Push"):
            return layout
        # The goal drawn with the layout only reserved room; the episode's goal is drawn anew, clear of the others.
        keepout = {kind: k for kind, k, _ in self.objects}
        others = [(*p, k) for (kind, k, _), p in zip(self.objects, xy) if kind != "goal"]
        goal = self.goal(i, others, keepout["goal"])
        if goal is None:
            raise LayoutError(f"safe_nav: no goal place found in {LAYOUT_TRIES} tries")
        layout["goal"] = goal
        return layout

    def choice(self, i: int, n: int) -> int:
        """One ``RandomState.choice(n)`` from env ``i``'s stream (the Button tasks' goal button)."""
        return int(self._rng(i).choice(n))

    def goal(self, i: int, others: list[tuple[float, float, float]], keepout: float) -> np.ndarray | None:
        """A goal place for env ``i`` clear of ``others`` (x, y, keep-out); None if none is found."""
        rng = self._rng(i)
        for _ in range(LAYOUT_TRIES):
            xy = self._draw(rng, keepout)
            if _clear(xy, keepout, others):
                return np.array(xy)
        return None

    def state_dict(self) -> dict[str, Any]:
        return {"rngs": [r.get_state() for r in self.rngs], "pending": self.pending.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        for rng, saved in zip(self.rngs, state["rngs"]):
            rng.set_state(saved)
        self.pending[:] = state["pending"]
