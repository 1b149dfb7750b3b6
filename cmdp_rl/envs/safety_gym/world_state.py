"""A Safety-Gymnasium navigation task's state as plain fields, and restoring it into a fresh task.

A task is a Python object graph (the builder, its task, world, agent and obstacles) around one
MuJoCo model and data. Its state is saved as that graph's fields, by attribute path, each node a
one-key dict:

- ``{"value": v}``: a number, string, array or plain container of them (the layout, counters, the
  goal's position, the world's MJCF);
- ``{"fields": {name: node}}``: an object of the package, its attributes in turn;
- ``{"items": [node, ...]}``, ``{"entries": {key: node}}``: a list, tuple or dict holding such
  objects (the obstacles, the geoms by name);
- ``{"set": [...]}``, ``{"random_state": ...}``: a set; numpy's legacy ``RandomState`` (its
  ``get_state(legacy=False)``, a dict of an array and numbers).

Restoring walks the same paths in a task built from the same id, setting each value on the live
object, so no object is created from what the file says: a saved state can only set numbers,
strings and arrays on the objects the code itself built. The model is rebuilt from the world's MJCF
plus its small arrays, which the task edits in place (a goal moved is a ``body_pos`` change; the
textures, 190 MB, are left out), and the data through ``env_state.mujoco_data_state``. An object
of another type in the graph stops the save with its path named, rather than save a state that would
resume inexactly.
"""

from __future__ import annotations

import copy
from typing import Any

import gymnasium as gym
import numpy as np

from cmdp_rl.envs.env_state import load_mujoco_data_state, mujoco_data_state

# Builder attributes that are configuration (rebuilt identically from the task id), not state.
BUILDER_CONFIG = {"render_parameters", "_ezpickle_args", "_ezpickle_kwargs", "config", "task_id"}
# Attributes that hold rendering or plumbing, never episode state.
_SKIPPED = {"viewer", "_viewers", "mujoco_renderer", "renderer"}
_MODEL_ARRAY_LIMIT = 1 << 20  # bytes: every model array but the textures (tex_data, 190 MB)


def _is_mujoco(value: Any) -> bool:
    return type(value).__module__.startswith("mujoco")


def _is_package_object(value: Any) -> bool:
    return type(value).__module__.startswith("safety_gymnasium") and hasattr(value, "__dict__")


def _plain(value: Any) -> bool:
    if value is None or isinstance(value, (bool, int, float, str, np.ndarray, np.generic)):
        return True
    if isinstance(value, (list, tuple)):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, (str, int)) and _plain(v) for k, v in value.items())
    return False


def _node(value: Any, where: str, seen: set[int]) -> dict[str, Any] | None:
    """``value`` as a node (module docstring); None for what is not state (skipped)."""
    if isinstance(value, (gym.spaces.Space, gym.envs.registration.EnvSpec)) or _is_mujoco(value) or callable(value):
        return None
    if _plain(value):
        return {"value": copy.deepcopy(value)}
    if isinstance(value, set) and _plain(list(value)):
        return {"set": sorted(value, key=repr)}
    if isinstance(value, np.random.RandomState):
        return {"random_state": value.get_state(legacy=False)}
    if _is_package_object(value):
        if id(value) in seen:  # shared (one engine, one agent): saved where first met
            return None
        seen.add(id(value))
        return {"fields": _fields(value, where, seen)}
    if isinstance(value, (list, tuple)):
        return {"items": [_node(v, f"{where}[{i}]", seen) for i, v in enumerate(value)]}
    if isinstance(value, dict) and all(isinstance(k, (str, int)) for k in value):
        return {"entries": {k: _node(v, f"{where}[{k!r}]", seen) for k, v in value.items()}}
    raise NotImplementedError(
        f"{where} is a {type(value).__module__}.{type(value).__name__}, which cmdp_rl cannot save, so a run on "
        "this task cannot resume exactly"
    )


def _fields(obj: Any, where: str, seen: set[int], skip: set[str] = frozenset()) -> dict[str, Any]:
    out = {}
    for name, value in vars(obj).items():
        if name in skip or name in _SKIPPED:
            continue
        node = _node(value, f"{where}.{name}", seen)
        if node is not None:
            out[name] = node
    return out


def _set(obj: Any, name: str, node: dict[str, Any], where: str) -> None:
    (kind, saved), live = next(iter(node.items())), getattr(obj, name, None)
    if kind == "value":
        if isinstance(live, np.ndarray) and isinstance(saved, np.ndarray) and live.shape == saved.shape:
            if live.flags.writeable and live.dtype == saved.dtype:
                live[...] = saved  # in place: keeps the array's type and whoever else holds it
                return
        setattr(obj, name, copy.deepcopy(saved))
    elif kind == "set":
        setattr(obj, name, set(saved))
    elif kind == "random_state":
        if not isinstance(live, np.random.RandomState):
            live = np.random.RandomState()
            setattr(obj, name, live)
        live.set_state(saved)
    elif kind == "fields":
        if live is None:
            raise ValueError(f"env: {where}.{name} is saved but this task has none")
        _load_fields(live, saved, f"{where}.{name}")
    elif kind in ("items", "entries"):
        keys = range(len(saved)) if kind == "items" else list(saved)
        if kind == "items" and (not isinstance(live, (list, tuple)) or len(live) != len(saved)):
            raise ValueError(f"env: {where}.{name} holds {len(saved)} saved items, this task another number")
        if kind == "entries" and (not isinstance(live, dict) or set(live) != set(keys)):
            raise ValueError(f"env: {where}.{name} holds other saved entries than this task")
        items = list(live) if kind == "items" else live
        for k in keys:
            if saved[k] is not None:
                _set(_Item(items, k), "value", saved[k], f"{where}.{name}[{k!r}]")
        if kind == "items":
            setattr(obj, name, items if isinstance(live, list) else tuple(items))
    else:
        raise ValueError(f"env: {where}.{name}: unknown saved node {kind!r}")


class _Item:
    """One list or dict slot as an attribute, so that :func:`_set` treats it as any other."""

    def __init__(self, items: list, index: int) -> None:
        self.__dict__["_items"], self.__dict__["_index"] = items, index

    def __getattr__(self, name: str) -> Any:
        return self._items[self._index]

    def __setattr__(self, name: str, value: Any) -> None:
        self._items[self._index] = value


def _load_fields(obj: Any, fields: dict[str, Any], where: str) -> None:
    for name, node in fields.items():
        _set(obj, name, node, where)


def _small_arrays(model: Any) -> dict[str, np.ndarray]:
    out = {}
    for name in dir(model):
        if name.startswith("_"):
            continue
        try:
            value = getattr(model, name)
        except Exception:  # noqa: BLE001 - a binding property that cannot be read here is not state
            continue
        if isinstance(value, np.ndarray) and value.nbytes <= _MODEL_ARRAY_LIMIT and value.flags.writeable:
            out[name] = value.copy()
    return out


def world_state(builder: Any) -> dict[str, Any]:
    """The state of a navigation task's builder (``safety_gymnasium.builder.Builder``)."""
    world = builder.task.world
    engine = None if world is None else world.engine
    return {
        "xml": None if world is None else world.xml_string,
        "model_arrays": None if engine is None else _small_arrays(engine.model),
        "data": None if engine is None else mujoco_data_state(engine.model, engine.data),
        "fields": _fields(builder, "builder", set(), BUILDER_CONFIG),
    }


def load_world_state(builder: Any, state: dict[str, Any]) -> None:
    """Restore :func:`world_state`'s ``state`` into a builder made from the same task id."""
    import mujoco

    if state["xml"] is not None and builder.task.world is None:
        builder.reset(seed=0)  # builds the world's objects; every field is then set from the state
    _load_fields(builder, state["fields"], "builder")
    if state["xml"] is None:
        return
    model = mujoco.MjModel.from_xml_string(state["xml"])
    for name, value in state["model_arrays"].items():
        getattr(model, name)[...] = value
    data = mujoco.MjData(model)
    load_mujoco_data_state(model, data, state["data"])
    builder.task.world.engine.update(model, data)


__all__ = ["BUILDER_CONFIG", "load_world_state", "world_state"]
