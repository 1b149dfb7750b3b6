"""Components by name: what ``algo=``, ``env=`` and ``policy=`` select. A component module declares its options and
registers itself when imported (``register("algo", "ppo", PPOConfig, PPO)``); nothing central lists them:
:func:`load_builtins` imports every module of ``cmdp_rl.algos``, ``cmdp_rl.envs`` and ``cmdp_rl.policies``, and a
user's own component is one ``register`` call in the user's code."""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from typing import Any, Callable

from cmdp_rl.config.validation import ConfigError

KINDS = ("algo", "env", "policy")
_PACKAGES = {"algo": "cmdp_rl.algos", "env": "cmdp_rl.envs", "policy": "cmdp_rl.policies"}
_NOUNS = {"algo": "algorithm", "env": "env", "policy": "policy"}


@dataclass(frozen=True)
class Component:
    kind: str
    name: str
    options: type  # the validated options dataclass (cmdp_rl.config.validation.options)
    build: Callable[..., Any]  # algo: (cfg, agent); env: (cfg, num_envs, device); policy: (cfg, env, normalizers)


_REGISTRY: dict[str, dict[str, Component]] = {k: {} for k in KINDS}
# The base class whose hooks the toolkit calls on a kind's options (AlgoConfig, EnvOptions), declared by the module
# that defines it, so that config.validate checks against it without importing those packages (they import this).
_BASES: dict[str, type] = {}
_loaded = False


def declare_base(kind: str, base: type) -> type:
    """Record ``base`` as the class every ``kind`` component's options derive from; returns it."""
    _BASES[kind] = base
    return base


def declared_base(kind: str) -> type | None:
    """The class :func:`declare_base` recorded for ``kind`` (None: any options class)."""
    load_builtins()
    return _BASES.get(kind)


def register(kind: str, name: str, options: type, build: Callable[..., Any]) -> Component:
    """Make ``options`` and ``build`` what ``<kind>=<name>`` selects. Registering a name again
    replaces it (a re-imported module, or a user's own version)."""
    if kind not in KINDS:
        raise ValueError(f"register: kind must be one of {KINDS}, got {kind!r}")
    component = Component(kind, name, options, build)
    _REGISTRY[kind][name] = component
    return component


def load_builtins() -> None:
    """Import every module of the component packages once, so their ``register`` calls run."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    for package in _PACKAGES.values():
        pkg = importlib.import_module(package)
        # walk_packages recurses, so an env family's sub-package (envs/reach1d/, ...) registers too
        for info in pkgutil.walk_packages(pkg.__path__, f"{package}."):
            importlib.import_module(info.name)


def component(kind: str, name: Any) -> Component:
    """The component registered as ``<kind>=<name>``, or a :class:`ConfigError` naming the field."""
    load_builtins()
    found = _REGISTRY[kind].get(name) if isinstance(name, str) else None
    if found is None:
        raise ConfigError(f"{kind}.name: unknown {_NOUNS[kind]} {name!r}; allowed: {names(kind)}")
    return found


def names(kind: str) -> list[str]:
    load_builtins()
    return sorted(_REGISTRY[kind])
