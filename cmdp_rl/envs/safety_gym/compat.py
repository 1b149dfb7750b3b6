"""Importing Safety-Gymnasium 1.0.0 (written for gymnasium 0.28, mujoco 2.3, Python <= 3.10) on our stack,
installed with ``--no-deps`` (``make setup-safety-gym``) and never edited. :func:`import_safety_gymnasium`
applies seven fixes, each only as far as needed (docs/safety_gym.md's table: what breaks and why): 1-3
only while the package imports (stand-ins for removed gymnasium modules and registration helpers, and
for ``gymnasium_robotics``); 4 hashable colour defaults; 5 ``MjModel.jnt`` taking a one-element array
(the one process-wide patch); 6 ``get_sensor``'s one-element readings; 7 the viewer's frame size.
``safety_gymnasium.make`` cannot run on gymnasium 1.x: ``env.make_task`` builds from the entry point."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import threading
import types
from typing import Any, Callable

import numpy as np

_lock = threading.Lock()
_COLOR_MODULE = "safety_gymnasium.assets.color"


class _HashableArray(np.ndarray):
    """A numpy array hashed by identity, which a dataclass accepts as a default (fix 4)."""

    __hash__ = object.__hash__


class _ColorFix(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Runs ``safety_gymnasium.assets.color``, then views its ``COLOR`` arrays as :class:`_HashableArray` (fix 4)."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != _COLOR_MODULE:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path, target)
        if spec is not None:
            self._inner, spec.loader = spec.loader, self
        return spec

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
    """Fix 1: gymnasium 0.28's module paths, pointing at 1.x's names."""
    import gymnasium.wrappers as wrappers
    from gymnasium.wrappers.utils import RunningMeanStd

    # 1.0 dropped the old-step-API converter; only make() uses it, for specs none of Safety-Gymnasium's are.
    compat = type("EnvCompatibility", (_Removed,), {})
    normalize = (wrappers.NormalizeObservation, wrappers.NormalizeReward, RunningMeanStd)
    names = {
        "compatibility": {"EnvCompatibility": compat},
        "autoreset": {"AutoResetWrapper": wrappers.Autoreset},
        "time_limit": {"TimeLimit": wrappers.TimeLimit},
        "env_checker": {"PassiveEnvChecker": wrappers.PassiveEnvChecker},
        "normalize": {c.__name__: c for c in normalize},
    }
    return {f"gymnasium.wrappers.{m}": _stub_module(f"gymnasium.wrappers.{m}", **attrs) for m, attrs in names.items()}


def _robotics_stand_ins() -> dict[str, types.ModuleType]:
    """Fix 3: its multi-agent tasks subclass gymnasium_robotics' MultiAgentMujocoEnv at import."""
    if importlib.util.find_spec("gymnasium_robotics") is not None:
        return {}
    env = type("MultiAgentMujocoEnv", (_Removed,), {})
    names = ["gymnasium_robotics", "gymnasium_robotics.envs", "gymnasium_robotics.envs.multiagent_mujoco"]
    mods = {n: _stub_module(n, __path__=[]) for n in names}
    mods["gymnasium_robotics.envs.multiagent_mujoco.mujoco_multi"] = _stub_module(
        "gymnasium_robotics.envs.multiagent_mujoco.mujoco_multi", MultiAgentMujocoEnv=env
    )
    return mods


def _patch(owner: Any, name: str, wrap: Callable[[Any], Any]) -> None:
    """``owner.<name> = wrap(original)``, once (the replacement is marked)."""
    original = getattr(owner, name)
    if not getattr(original, "_cmdp_rl_compat", False):
        patched = wrap(original)
        patched._cmdp_rl_compat = True
        setattr(owner, name, patched)


def _jnt(original):
    """Fix 5: ``MjModel.jnt`` accepts a one-element integer array again."""

    def jnt(self, key):
        if isinstance(key, np.ndarray) and key.size == 1 and np.issubdtype(key.dtype, np.integer):
            key = int(key.reshape(()))
        return original(self, key)

    return jnt


class _OneElement(np.ndarray):
    """A one-element sensor reading whose ``float()`` is its element (fix 6)."""

    def __float__(self) -> float:
        return float(np.asarray(self).reshape(()))


def _get_sensor(original):
    """Fix 6, on Safety-Gymnasium's ``BaseAgent`` only."""

    def get_sensor(self, name: str) -> np.ndarray:
        value = original(self, name)
        return value.view(_OneElement) if value.size == 1 else value

    return get_sensor


def _offscreen_viewer(viewer):
    """Fix 7, on the name its ``underlying`` module calls (gymnasium's class is untouched)."""

    def offscreen_viewer(model, data, width=None, height=None, **kwargs):
        width = model.vis.global_.offwidth if width is None else width
        height = model.vis.global_.offheight if height is None else height
        return viewer(model, data, width, height, **kwargs)

    return offscreen_viewer


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
        # Fix 2: 0.28's registration helpers ``_check_metadata`` (which only warned on odd metadata) and ``_find_spec``.
        helpers = {"_check_metadata": lambda metadata: None, "_find_spec": registration.spec}
        helpers = {k: v for k, v in helpers.items() if not hasattr(registration, k)}
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
        import mujoco

        _patch(mujoco.MjModel, "jnt", _jnt)
        _patch(importlib.import_module("safety_gymnasium.bases.base_agent").BaseAgent, "get_sensor", _get_sensor)
        _patch(importlib.import_module("safety_gymnasium.bases.underlying"), "OffScreenViewer", _offscreen_viewer)
        return module
