"""A Safety-Gymnasium navigation task's state as plain fields, and restoring it into a fresh task (docs/checkpoints.md).
The object graph (builder, task, world, agent, obstacles) is saved by attribute path, each node a one-key dict:
``value`` (a number, string, array or plain container), ``fields`` (an object of the package), ``items`` / ``entries``
(a list, tuple or dict holding such objects), ``set``, ``random_state``. Restoring walks the same paths in a task built
from the same id and only sets values on objects the code built. The model is rebuilt from the MJCF plus its small
arrays; an object of an unknown type stops the save with its path named, rather than resume inexactly."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from cmdp_rl.envs.env_state import _plain, _static, load_mujoco_data_state, mujoco_data_state

# Builder attributes that are configuration (rebuilt identically from the task id), not state.
BUILDER_CONFIG = {"render_parameters", "_ezpickle_args", "_ezpickle_kwargs", "config", "task_id"}
# Attributes that hold rendering or plumbing, never episode state.
_SKIPPED = {"viewer", "_viewers", "mujoco_renderer", "renderer"}
_MODEL_ARRAY_LIMIT = 1 << 20  # bytes: every model array but the textures (tex_data, 190 MB)


def _node(value: Any, where: str, seen: set[int]) -> dict[str, Any] | None:
    """``value`` as a node (module docstring); None for what is not state (skipped)."""
    if _static(value) or type(value).__module__.startswith("mujoco") or callable(value):
        return None
    if _plain(value):
        return {"value": copy.deepcopy(value)}
    if isinstance(value, set) and _plain(list(value)):
        return {"set": sorted(value, key=repr)}
    if isinstance(value, np.random.RandomState):
        return {"random_state": value.get_state(legacy=False)}
    if type(value).__module__.startswith("safety_gymnasium") and hasattr(value, "__dict__"):
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


def _fields(obj: Any, where: str, seen: set[int], skip: set[str] = _SKIPPED) -> dict[str, Any]:
    nodes = {name: _node(value, f"{where}.{name}", seen) for name, value in vars(obj).items() if name not in skip}
    return {name: node for name, node in nodes.items() if node is not None}


def _restored(live: Any, node: dict[str, Any], where: str) -> Any:
    """What ``live`` (at ``where`` in a fresh task) becomes from ``node``: updated in place where it can be."""
    ((kind, saved),) = node.items()
    if kind == "value":
        same = isinstance(live, np.ndarray) and isinstance(saved, np.ndarray) and live.shape == saved.shape
        if same and live.flags.writeable and live.dtype == saved.dtype:
            live[...] = saved
            return live
        return copy.deepcopy(saved)
    if kind == "set":
        return set(saved)
    if kind == "random_state":
        live = live if isinstance(live, np.random.RandomState) else np.random.RandomState()
        live.set_state(saved)
        return live
    if kind == "fields":
        if live is None:
            raise ValueError(f"env: {where} is saved but this task has none")
        _load_fields(live, saved, where)
        return live
    if kind == "items" and (not isinstance(live, (list, tuple)) or len(live) != len(saved)):
        raise ValueError(f"env: {where} holds {len(saved)} saved items, this task another number")
    if kind == "entries" and (not isinstance(live, dict) or set(live) != set(saved)):
        raise ValueError(f"env: {where} holds other saved entries than this task")
    if kind not in ("items", "entries"):
        raise ValueError(f"env: {where}: unknown saved node {kind!r}")
    items = list(live) if kind == "items" else live
    for k in range(len(saved)) if kind == "items" else list(saved):
        if saved[k] is not None:
            items[k] = _restored(items[k], saved[k], f"{where}[{k!r}]")
    return tuple(items) if isinstance(live, tuple) else items


def _load_fields(obj: Any, fields: dict[str, Any], where: str) -> None:
    for name, node in fields.items():
        setattr(obj, name, _restored(getattr(obj, name, None), node, f"{where}.{name}"))


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
        "fields": _fields(builder, "builder", set(), BUILDER_CONFIG | _SKIPPED),
    }


def saved_model(state: dict[str, Any]) -> Any:
    """The ``MjModel`` a saved world holds: compiled from its MJCF, then its small arrays set."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(state["xml"])
    for name, value in state["model_arrays"].items():
        getattr(model, name)[...] = value
    return model


def load_world_state(builder: Any, state: dict[str, Any]) -> None:
    """Restore :func:`world_state`'s ``state`` into a builder made from the same task id."""
    import mujoco

    if state["xml"] is not None and builder.task.world is None:
        builder.reset(seed=0)  # builds the world's objects; every field is then set from the state
    _load_fields(builder, state["fields"], "builder")
    if state["xml"] is None:
        return
    model = saved_model(state)
    data = mujoco.MjData(model)
    load_mujoco_data_state(model, data, state["data"])
    builder.task.world.engine.update(model, data)
