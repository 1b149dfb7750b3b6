"""Importing Safety-Gymnasium 1.0.0 on our stack (gymnasium 1.x, mujoco 3+/4, numpy 2, Python 3.11).

Safety-Gymnasium's only release was written for gymnasium 0.28, mujoco 2.3 and Python <= 3.10
(``/work/shared/notes/safety-gymnasium-facts.md`` records what breaks). It is installed with
``--no-deps`` (``make setup-safety-gym``) and never edited; :func:`import_safety_gymnasium` makes
the import work with the fixes below, each applied only as far as needed:

1. gymnasium 1.0 removed or renamed modules it imports at package import time; stand-ins for them
   sit in ``sys.modules`` only while it imports, and are taken out afterwards.
2. gymnasium 1.0 removed two private helpers of ``gymnasium.envs.registration`` that its
   ``registration`` module imports by name; set there only while it imports, then deleted again.
3. Its multi-agent tasks import ``gymnasium_robotics``: a stand-in module while it imports, unless
   the real package is installed (the ``safety_gym`` extra installs it; ``multi_agent.py`` builds
   those tasks).
4. Python 3.11's dataclasses refuse unhashable defaults, and its colour defaults are numpy arrays:
   an import hook makes those arrays hashable right after ``safety_gymnasium.assets.color`` runs.
5. mujoco 3 made ``MjModel.jnt`` accept only an int or a name; its Car, Racecar and Doggo robots
   pass a one-element array (a sensor's ``objid``). The one process-wide patch: ``MjModel.jnt``
   also accepts a one-element integer array, as mujoco 2.3 did. Calls that worked still do the same.
6. numpy 2 turned ``float()`` of a one-element 1-D array into a TypeError (deprecated since numpy
   1.25); its Doggo and Ant robots read their hinge angles that way. ``BaseAgent.get_sensor`` (in
   Safety-Gymnasium's own class, not numpy's) returns its one-element readings as an array type whose
   ``float()`` takes the one element; values, shapes and dtypes are unchanged.
7. gymnasium 1.0's ``OffScreenViewer`` requires ``width`` and ``height``; 0.28's took them from the
   model's offscreen buffer size, which the package sets to the frame size just before it creates
   its viewer (``rgb_array`` rendering, for videos). The name its ``underlying`` module uses is
   rebound to a function passing that size on; rendering is otherwise the package's.

``safety_gymnasium.make`` itself cannot run on gymnasium 1.x (it reads and writes ``EnvSpec``
fields 1.0 removed, such as ``apply_api_compatibility``), so :func:`make_task` builds a task from its
registered entry point and registered kwargs, as ``make`` does, adding only the time limit.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import threading
import types
from typing import Any

import numpy as np

_lock = threading.Lock()
_COLOR_MODULE = "safety_gymnasium.assets.color"


class _HashableArray(np.ndarray):
    """A numpy array hashed by identity: a dataclass accepts it as a field default (fix 4)."""

    __hash__ = object.__hash__


class _ColorFix(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Runs ``safety_gymnasium.assets.color`` unchanged, then views its ``COLOR`` arrays as
    :class:`_HashableArray` (same data, same dtype) before any dataclass reads them (fix 4)."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != _COLOR_MODULE:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                self._inner = spec.loader
                spec.loader = self
                return spec
        return None

    def create_module(self, spec):
        return self._inner.create_module(spec)

    def exec_module(self, module):
        self._inner.exec_module(module)
        module.COLOR = {k: np.asarray(v).view(_HashableArray) for k, v in module.COLOR.items()}


def _stub_module(name: str, **attrs: Any) -> types.ModuleType:
    module = types.ModuleType(name)
    module.__dict__.update(attrs)
    return module


class _Removed:
    """Stands for a gymnasium 0.28 class that 1.x removed and that nothing we offer uses."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        raise NotImplementedError(f"{type(self).__name__}: removed in gymnasium 1.0, not supported here")


def _gymnasium_stand_ins() -> dict[str, types.ModuleType]:
    """Fix 1: the gymnasium 0.28 module paths Safety-Gymnasium imports, pointing at 1.x's names."""
    import gymnasium.wrappers as wrappers
    from gymnasium.wrappers.utils import RunningMeanStd

    # gymnasium 1.0 dropped the old-step-API converter (moved to shimmy); only make() uses it, and
    # only for specs that ask for it, which none of Safety-Gymnasium's do.
    compat = type("EnvCompatibility", (_Removed,), {})
    return {
        "gymnasium.wrappers.compatibility": _stub_module("gymnasium.wrappers.compatibility", EnvCompatibility=compat),
        # AutoResetWrapper was renamed Autoreset in gymnasium 1.0.
        "gymnasium.wrappers.autoreset": _stub_module(
            "gymnasium.wrappers.autoreset", AutoResetWrapper=wrappers.Autoreset
        ),
        # 1.0 folded time_limit, env_checker and normalize into gymnasium.wrappers.common / stateful_*;
        # RunningMeanStd moved to gymnasium.wrappers.utils.
        "gymnasium.wrappers.time_limit": _stub_module("gymnasium.wrappers.time_limit", TimeLimit=wrappers.TimeLimit),
        "gymnasium.wrappers.env_checker": _stub_module(
            "gymnasium.wrappers.env_checker", PassiveEnvChecker=wrappers.PassiveEnvChecker
        ),
        "gymnasium.wrappers.normalize": _stub_module(
            "gymnasium.wrappers.normalize",
            NormalizeObservation=wrappers.NormalizeObservation,
            NormalizeReward=wrappers.NormalizeReward,
            RunningMeanStd=RunningMeanStd,
        ),
    }


def _robotics_stand_ins() -> dict[str, types.ModuleType]:
    """Fix 3: the multi-agent tasks subclass gymnasium_robotics' MultiAgentMujocoEnv at import."""
    if importlib.util.find_spec("gymnasium_robotics") is not None:
        return {}
    env = type("MultiAgentMujocoEnv", (_Removed,), {})
    names = ["gymnasium_robotics", "gymnasium_robotics.envs", "gymnasium_robotics.envs.multiagent_mujoco"]
    mods = {n: _stub_module(n, __path__=[]) for n in names}
    mods["gymnasium_robotics.envs.multiagent_mujoco.mujoco_multi"] = _stub_module(
        "gymnasium_robotics.envs.multiagent_mujoco.mujoco_multi", MultiAgentMujocoEnv=env
    )
    return mods


def _registration_helpers() -> dict[str, Any]:
    """Fix 2: ``_check_metadata`` and ``_find_spec`` of gymnasium 0.28's registration module."""

    def _check_metadata(metadata: dict) -> None:  # 0.28 only warned on odd metadata
        pass

    def _find_spec(env_id: str):
        import gymnasium

        return gymnasium.spec(env_id)

    return {"_check_metadata": _check_metadata, "_find_spec": _find_spec}


def _patch_mjmodel_jnt() -> None:
    """Fix 5: ``MjModel.jnt`` accepts a one-element integer array again (mujoco 2.3 did)."""
    import mujoco

    original = mujoco.MjModel.jnt
    if getattr(original, "_cmdp_rl_compat", False):
        return

    def jnt(self, key):
        if isinstance(key, np.ndarray) and key.size == 1 and np.issubdtype(key.dtype, np.integer):
            key = int(key.reshape(()))
        return original(self, key)

    jnt._cmdp_rl_compat = True
    mujoco.MjModel.jnt = jnt


class _OneElement(np.ndarray):
    """A one-element sensor reading whose ``float()`` is its element, as numpy 1.x allowed (fix 6)."""

    def __float__(self) -> float:
        return float(np.asarray(self).reshape(()))


def _patch_get_sensor(base_agent: type) -> None:
    """Fix 6, on Safety-Gymnasium's ``BaseAgent`` only."""
    original = base_agent.get_sensor
    if getattr(original, "_cmdp_rl_compat", False):
        return

    def get_sensor(self, name: str) -> np.ndarray:
        value = original(self, name)
        return value.view(_OneElement) if value.size == 1 else value

    get_sensor._cmdp_rl_compat = True
    base_agent.get_sensor = get_sensor


def _patch_offscreen_viewer(underlying: types.ModuleType) -> None:
    """Fix 7, on the name Safety-Gymnasium's ``underlying`` module calls (gymnasium's class is untouched)."""
    viewer = underlying.OffScreenViewer
    if getattr(viewer, "_cmdp_rl_compat", False):
        return

    def offscreen_viewer(model, data, width=None, height=None, **kwargs):
        width = model.vis.global_.offwidth if width is None else width
        height = model.vis.global_.offheight if height is None else height
        return viewer(model, data, width, height, **kwargs)

    offscreen_viewer._cmdp_rl_compat = True
    underlying.OffScreenViewer = offscreen_viewer


def import_safety_gymnasium() -> types.ModuleType:
    """``import safety_gymnasium`` with the fixes above; an ImportError saying how to install it."""
    if "safety_gymnasium" in sys.modules:
        return sys.modules["safety_gymnasium"]
    if importlib.util.find_spec("safety_gymnasium") is None:
        raise ImportError(
            "env=safety_gym needs Safety-Gymnasium: run `make setup-safety-gym` "
            "(installs safety-gymnasium==1.0.0 with --no-deps and the extra `safety_gym`)"
        )
    with _lock:
        if "safety_gymnasium" in sys.modules:
            return sys.modules["safety_gymnasium"]
        import gymnasium.envs.registration as registration

        stand_ins = {**_gymnasium_stand_ins(), **_robotics_stand_ins()}
        stand_ins = {k: v for k, v in stand_ins.items() if k not in sys.modules}
        helpers = {k: v for k, v in _registration_helpers().items() if not hasattr(registration, k)}
        finder = _ColorFix()
        sys.modules.update(stand_ins)
        for k, v in helpers.items():
            setattr(registration, k, v)
        sys.meta_path.insert(0, finder)
        try:
            module = importlib.import_module("safety_gymnasium")
        finally:
            sys.meta_path.remove(finder)
            for k in helpers:
                delattr(registration, k)
            for k in stand_ins:
                sys.modules.pop(k, None)
        _patch_mjmodel_jnt()
        _patch_get_sensor(importlib.import_module("safety_gymnasium.bases.base_agent").BaseAgent)
        _patch_offscreen_viewer(importlib.import_module("safety_gymnasium.bases.underlying"))
        return module


__all__ = ["import_safety_gymnasium"]
