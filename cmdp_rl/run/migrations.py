"""Checkpoints and saved configs of older formats, brought to the current layout: every compatibility rule lives
here, keyed on the format a checkpoint was written in (:data:`STEPS`), so the algorithms, envs and trainer read only
the current one. What each step changes, and why format 2 loads only on the user's word (its files pickle numpy
objects and may hold pickled bytes): docs/checkpoints.md, "Old run directories". ``python -m cmdp_rl.run.convert``
applies these rules to a run's files once."""

from __future__ import annotations

import io
import pickle
from typing import Any, Callable

import torch
from torch import nn

from cmdp_rl.config.saved import deploy_node, flat_keys, into_node
from cmdp_rl.envs.env_state import mujoco_data_state
from cmdp_rl.run.checkpoint import FORMAT_VERSION

# --- networks of the ActorCritic triple (before the agent model) ---------------------------------
# The same modules built in the same order under other names (the actor was a ProbabilisticActor around TensorDict
# modules, the critics ``critic.`` and ``cost_critic.``), so network by network the old entries are the new ones in
# order, each pair agreeing in shape and last name; the observation statistics, which sat inside every network, come
# from ``normalizers.``, the one copy the agent's networks share. Optimizer states, in the same order, need no change.
NETWORKS = {"actor.": "actor.", "critic.": "critics.reward.", "cost_critic.": "critics.cost."}
NORMALIZERS = "normalizers."

# Format 2's writers of one multiplier state per constraint, which saved a single constraint's as the bare
# controller state (a closed list: format 2 is no longer written).
_PER_CONSTRAINT = ("ppo_lag", "pid_lag", "trpo_lag", "sac_lag", "td3_lag")


def is_legacy(networks: dict) -> bool:
    """Whether a checkpoint's network state is the old ``ActorCritic``'s."""
    return any(k.startswith(("critic.", "cost_critic.")) for k in networks)


def convert_networks(networks: dict[str, torch.Tensor], agent: nn.Module) -> dict[str, torch.Tensor]:
    """An old ``ActorCritic`` state dict as ``agent``'s state dict. Raises ``KeyError`` naming the
    first entry that does not fit."""
    target = agent.state_dict(keep_vars=True)
    out: dict[str, torch.Tensor] = {k: v for k, v in networks.items() if k.startswith(NORMALIZERS)}
    # Every alias of a normalizer's statistics in the agent is the same tensor as under normalizers.
    shared = {v.data_ptr(): k for k, v in target.items() if k.startswith(NORMALIZERS)}
    for key, value in target.items():
        if key.startswith(NORMALIZERS):
            continue
        if value.data_ptr() in shared:
            source = shared[value.data_ptr()]
            if source not in out:
                raise KeyError(f"old checkpoint lacks {source!r} (the statistics of {key!r})")
            out[key] = out[source]
    for old_prefix, new_prefix in NETWORKS.items():
        # Not an observation normalizer's running statistics (``...stats.mean``), which normalizers.obs holds.
        old = [k for k in networks if k.startswith(old_prefix) and ".stats." not in k and not k.startswith("stats.")]
        # The old MLP actor kept its input encoder (previous action and cost) inside the Gaussian
        # head's network (``...module.net.encoder.``); the agent keeps it in the body, which comes first.
        old.sort(key=lambda k: 0 if ".module.net.encoder." in k else 1)
        new = [k for k in target if k.startswith(new_prefix) and k not in out]
        if len(old) != len(new):
            raise KeyError(
                f"old checkpoint has {len(old)} entries under {old_prefix!r}, the agent {len(new)} under {new_prefix!r}"
            )
        for o, n in zip(old, new):
            if o.rsplit(".", 1)[-1] != n.rsplit(".", 1)[-1] or networks[o].shape != target[n].shape:
                raise KeyError(
                    f"old checkpoint entry {o!r} {tuple(networks[o].shape)} does not fit {n!r} {tuple(target[n].shape)}"
                )
            out[n] = networks[o]
    missing = target.keys() - out.keys()
    if missing:
        raise KeyError(f"old checkpoint has nothing for {sorted(missing)[:3]}")
    return out


# --- format 2 -> 3 -------------------------------------------------------------------------------
def _algo_state_from_2(algo: str | None, state: dict[str, Any], agent: nn.Module | None) -> dict[str, Any]:
    state = dict(state)
    if agent is not None and "networks" in state and is_legacy(state["networks"]):
        state["networks"] = convert_networks(state["networks"], agent)
    if "targets" not in state:  # on-policy: the shared J_c estimate, the learning-rate clock
        if "episode_cost" not in state:
            estimate = state.pop("episode_estimate", None)  # CPO's last J_c, before the shared estimate
            state["episode_cost"] = {"recent": [tuple(estimate)]} if estimate is not None else {}
        state.setdefault("iteration", 0)
    return _per_constraint_from_2(state) if algo in _PER_CONSTRAINT else state


def _per_constraint_from_2(state: dict[str, Any]) -> dict[str, Any]:
    """A single constraint's multiplier state, saved bare, under ``constraints`` as with K > 1."""
    bare = state.get("multiplier")
    return {**state, "multiplier": {"constraints": [bare]}} if bare and "constraints" not in bare else state


def _mujoco_from_2(env: dict[str, Any]) -> dict[str, Any]:
    """A gymnasium env's state (``envs/env_state.py``) whose ``MjData`` was pickled whole."""
    env = dict(env)
    data = pickle.loads(env.pop("mujoco_data"))  # trusted: the caller loaded a format 2 file on the user's word
    env["mujoco"] = mujoco_data_state(data.model, data)
    return env


def _safety_gym_world_from_2(state: dict[str, Any], task: str) -> dict[str, Any]:
    """A navigation task's state whose world was pickled whole (with its one model and data saved
    apart: the MJCF and small arrays, MuJoCo's integration state): restored into a task built from
    the run's id the way format 2 did, then saved as format 3 saves it."""
    import mujoco

    from cmdp_rl.envs.safety_gym.env import make_task
    from cmdp_rl.envs.safety_gym.world_state import saved_model

    model = None if state["xml"] is None else saved_model(state)

    class Format2Unpickler(pickle.Unpickler):  # trusted: the user's word on a format 2 file
        data = None

        def persistent_load(self, pid: tuple) -> Any:
            if pid[0] == "model":
                return model
            if self.data is None:
                self.data = mujoco.MjData(model)
                mujoco.mj_setState(model, self.data, pid[1], mujoco.mjtState.mjSTATE_INTEGRATION)
                mujoco.mj_forward(model, self.data)
            return self.data

    env = make_task(task)
    try:
        vars(env.inner).update(Format2Unpickler(io.BytesIO(state["builder"])).load())
        env.steps = state["steps"]
        return env.state_dict()
    finally:
        env.close()


def _envs_from_2(value: Any, config: dict[str, Any]) -> Any:
    """Every env state inside a collector state, in format 3's layout."""
    if isinstance(value, dict):
        if "builder" in value:  # a Safety-Gymnasium navigation task's world, pickled
            return _safety_gym_world_from_2(value, config["env"]["task"])
        value = {k: _envs_from_2(v, config) for k, v in value.items()}
        return _mujoco_from_2(value) if "mujoco_data" in value else value
    if isinstance(value, (list, tuple)):
        return type(value)(_envs_from_2(v, config) for v in value)
    return value


def _from_2(state: dict[str, Any], agent: nn.Module | None) -> dict[str, Any]:
    state = dict(state)
    if "algo_state" in state:  # a run's checkpoint
        state["algo_state"] = _algo_state_from_2(state.get("algo"), state["algo_state"], agent)
        if state.get("collector") is not None:
            state["collector"] = _envs_from_2(state["collector"], state.get("config") or {})
    if "update" in state:  # a population's (cmdp_rl/population/): PPO family, Multipliers where any
        state["update"] = {**state["update"], "algos": [_per_constraint_from_2(a) for a in state["update"]["algos"]]}
    return state


# --- format 3 -> 4 -------------------------------------------------------------------------------
# What a checkpoint shares among its members; the rest of a format 3 run's (or population agent's)
# checkpoint is its member entry.
SHARED = ("algo", "policy", "iteration", "step", "time_s", "collector")


def _entry_from_3(entry: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in entry.items() if k not in (*SHARED, "rng", "format", "population")}


def _from_3(state: dict[str, Any], agent: nn.Module | None) -> dict[str, Any]:
    """One layout for runs and populations: a run's ``checkpoint.pt`` (its entry at the top level) and
    a population's ``population.pt`` (``agents``, ``generators``, ``costs``) as the shared state with
    ``members``. A population of the stacked layout (``update``) stays as it is: its entries are built
    from its agents' configs at its resume (:func:`population_from_stacked`)."""
    if "algo_state" in state:
        members = [_entry_from_3(state)]
        rng = state.get("rng")
    elif "agents" in state:
        members = [_entry_from_3(e) for e in state["agents"]]
        rng = {"generators": state["generators"]}
    else:
        return state
    out = {**{k: state.get(k) for k in SHARED}, "rng": rng, "members": members}
    if "costs" in state:
        out["costs"] = state["costs"]
    return out


# The step from each format to the next.
STEPS: dict[int, Callable[[dict[str, Any], nn.Module | None], dict[str, Any]]] = {2: _from_2, 3: _from_3}


def member(state: dict[str, Any], i: int = 0) -> dict[str, Any]:
    """Member ``i``'s entry (config, algorithm state, deployed policy) of a checkpoint as loaded, of
    any format (before :func:`migrate`: a format 3 run's entry is the checkpoint itself)."""
    if "members" in state:
        return state["members"][i]
    return state["agents"][i] if "agents" in state else state


def migrate(state: dict[str, Any], agent: nn.Module | None = None) -> dict[str, Any]:
    """``state`` (as :func:`~cmdp_rl.run.checkpoint.load_checkpoint` returned it) in the current format's layout.
    ``agent``, the run's, names the networks of a checkpoint from before the agent model (without it: left as is)."""
    version = state["format"]
    for v in range(version, FORMAT_VERSION):
        state = STEPS[v](state, agent)
    return {**state, "format": FORMAT_VERSION}


# --- a population's checkpoint of the stacked layout ----------------------------------------------
def population_from_stacked(
    state: dict[str, Any], entries: list[dict[str, Any]], modules: dict[str, nn.Module]
) -> dict[str, Any]:
    """A population checkpoint of the stacked layout (every agent's networks as rows of ``actor`` and
    ``critics``, the optimisers' moments as rows under ``update``, as written up to commit 8dc7aaa)
    in the current layout, one member entry per agent. ``entries`` are the agents' entries as
    freshly built (their configs, optimiser settings and algorithm state to fill in); ``modules``
    names the ``actor`` and ``critics`` of one agent, whose parameter order the rows follow."""
    update = state["update"]
    out = []
    for i, entry in enumerate(entries):
        algo_state = {**entry["algo_state"], **update["algos"][i]}
        networks = dict(algo_state["networks"])
        for name, opt_name in (("actor", "actor_opt"), ("critics", "critic_opt")):
            saved = update[opt_name]
            steps = saved["steps"][i] if "steps" in saved else saved["step"]  # one count for all, earlier
            at, moments = 0, {}
            for j, (n, p) in enumerate(modules[name].named_parameters()):
                rows = slice(at, at + p.numel())
                at += p.numel()
                networks[f"{name}.{n}"] = state[name][i, rows].reshape(p.shape).clone()
                moments[j] = {
                    "step": torch.tensor(float(steps)),
                    **{k: saved[k][i, rows].reshape(p.shape).clone() for k in ("exp_avg", "exp_avg_sq")},
                }
            algo_state[opt_name] = {**entry["algo_state"][opt_name], "state": moments if float(steps) else {}}
        algo_state["networks"] = networks
        out.append({**entry, "algo_state": algo_state})
    shared = {k: v for k, v in state.items() if k in (*SHARED, "costs")}
    return {**shared, "rng": {"generators": state["generators"]}, "members": out}


# --- saved configs -------------------------------------------------------------------------------
# The defaults a config saved before ``mixture_weights`` existed ran with, wherever it names none.
_RUN_DEFAULTS_BEFORE_MIXTURE_WEIGHTS = {
    "final_policy": "last",
    "average_last": 0.25,
    "mixture_size": 8,
    "mixture_weights": "uniform",
}

# The multiplier's flat options before the node ``algo.multiplier``, each by its name there. ``multiplier`` was the
# update's name (pid_lag had none: always PID); FOCOPS's nu was PID's integral term clamped at nu_max, the node's dual
# ascent with max, the same numbers. ``anneal_lambda_lr`` (None) is gone: a run saved with it true resumes with a
# constant step.
_FLAT_MULTIPLIER = {
    "multiplier": "kind",
    **{f"lambda_{k}": k for k in ("lr", "init", "scale", "tau", "nu", "max")},
    **{k: k for k in ("kp", "ki", "kd", "p_ema_alpha", "d_ema_alpha", "d_delay")},
    **{f"nu_{k}": k for k in ("init", "lr", "max", "scale")},  # FOCOPS's and CUP's cost multiplier
    "anneal_lambda_lr": None,
}


def _has_multiplier_node(name: Any) -> bool:
    import dataclasses

    from cmdp_rl.config.registry import component

    return isinstance(name, str) and "multiplier" in {
        f.name for f in dataclasses.fields(component("algo", name).options)
    }


def multiplier_node(algo: dict[str, Any]) -> dict[str, Any]:
    """An algorithm's saved options with the flat multiplier options of older configs moved into the node
    (:data:`_FLAT_MULTIPLIER`), and the node of a config saved before each kind had its own options (every kind's
    13 fields, the other kinds' unread) cut to its kind's. Fields the old config does not name take the
    algorithm's defaults when it is built."""
    name = algo.get("name", "ppo_lag")
    if not _has_multiplier_node(name):
        return algo
    kindless_pid = name == "pid_lag" and not isinstance(algo.get("multiplier"), dict)
    if flat_keys(algo, _FLAT_MULTIPLIER, "multiplier") or kindless_pid:
        # Flat options ran with the kind of their day where they name none: pid_lag's PID, the others' dual ascent.
        day = {} if isinstance(algo.get("multiplier"), str) else {"kind": "pid" if name == "pid_lag" else "dual"}
        algo = into_node(algo, _FLAT_MULTIPLIER, "multiplier", **day)
    return {**algo, "multiplier": _own_fields(algo["multiplier"])} if isinstance(algo.get("multiplier"), dict) else algo


def _own_fields(node: dict[str, Any]) -> dict[str, Any]:
    """A saved multiplier node with only its kind's options (a node that names no kind is the default's; an
    unknown kind is left for the config's check to name)."""
    from cmdp_rl.algos.multiplier_options import KINDS

    kind = node.get("kind")
    if kind not in KINDS:
        return node
    own = KINDS[kind].__pydantic_fields__
    return {k: v for k, v in node.items() if k in own}


def _anneal_span(algo: dict[str, Any]) -> dict[str, Any]:
    """The PPO family's ``anneal_iterations`` (the span of an annealing switched on by ``anneal_lr: true``) became
    ``anneal_lr``'s value: the span where it was on, nothing where it was off (the span was unread)."""
    if "anneal_iterations" not in algo:
        return algo
    out = {k: v for k, v in algo.items() if k != "anneal_iterations"}
    if out.get("anneal_lr") is True:
        out["anneal_lr"] = algo["anneal_iterations"]
    return out


def saved_config_nodes(config: dict[str, Any]) -> dict[str, Any]:
    """A saved config (a run's, or a population's with its grid) with the options that became nodes in the nodes
    (:func:`multiplier_node`; a population's ``grid.algo.<flat>`` as ``grid.algo.multiplier.<field>``)."""
    out = dict(config)
    if isinstance(out.get("algo"), dict):
        out["algo"] = multiplier_node(_anneal_span(out["algo"]))
    grid = (out.get("population") or {}).get("grid") or {}
    varied = grid.get("algo") if isinstance(grid, dict) else None
    name = (out.get("algo") or {}).get("name", "ppo_lag")
    if isinstance(varied, dict) and _has_multiplier_node(name) and flat_keys(varied, _FLAT_MULTIPLIER, "multiplier"):
        varied = into_node(varied, _FLAT_MULTIPLIER, "multiplier")
        out["population"] = {**out["population"], "grid": {**grid, "algo": varied}}
    return out


def saved_config_defaults(config: dict[str, Any]) -> dict[str, Any]:
    """A saved run config with the defaults it ran with made explicit (a run config written since ``mixture_weights``
    existed records every option), in the current layout (:func:`saved_config_nodes`, :func:`deploy_node`)."""
    config = _advantage_scale_of_its_day(config)
    if "mixture_weights" not in config and "deploy" not in config:
        config = {**_RUN_DEFAULTS_BEFORE_MIXTURE_WEIGHTS, **config}
        algo = dict(config.get("algo") or {})
        name = algo.get("name", "ppo_lag")
        if _has_multiplier_node(name):  # its scale was none then; flat, as the config's other multiplier options
            algo.setdefault("nu_scale" if name in ("focops", "cup") else "lambda_scale", "none")
        config["algo"] = algo
    return _log_saturation_of_its_day(deploy_node(saved_config_nodes(config)))


def _log_saturation_of_its_day(config: dict[str, Any]) -> dict[str, Any]:
    """A saved config whose log dual names no ``saturation`` ran before the option existed, with the step in
    proportion to the violation up to J_c = 2d (saturation 1; the default became 0.25 later)."""
    algo = config.get("algo")
    node = algo.get("multiplier") if isinstance(algo, dict) else None
    if not isinstance(node, dict) or node.get("kind") != "log" or "saturation" in node:
        return config
    return {**config, "algo": {**algo, "multiplier": {**node, "saturation": 1.0}}}


def _advantage_scale_of_its_day(config: dict[str, Any]) -> dict[str, Any]:
    """A saved run config that names no ``advantage_scale`` for an algorithm that has one ran before the option
    existed, on raw advantages (ppo_lag's default became standardized later; a saved config records every option)."""
    import dataclasses

    from cmdp_rl.config.registry import component
    from cmdp_rl.config.validation import ConfigError

    algo = config.get("algo")
    if not isinstance(algo, dict) or "advantage_scale" in algo:
        return config
    try:
        fields = {f.name for f in dataclasses.fields(component("algo", algo.get("name", "ppo_lag")).options)}
    except ConfigError:  # an unknown algorithm: the config's check names it
        return config
    return {**config, "algo": {**algo, "advantage_scale": "raw"}} if "advantage_scale" in fields else config


def recorded_defaults(author: dict[str, Any], recorded: dict[str, Any]) -> dict[str, Any]:
    """An author's config (a population.yaml names only what its author gave) with the options whose default has
    changed since taken, where it names none, from the config a member recorded: what the run was trained with."""
    algo = dict(author.get("algo") or {})
    ran = saved_config_defaults(recorded).get("algo") or {}
    if "advantage_scale" in ran:
        algo.setdefault("advantage_scale", ran["advantage_scale"])
    node, ran_node = algo.get("multiplier"), ran.get("multiplier")
    if isinstance(ran_node, dict) and "kind" in ran_node and isinstance(node, (dict, type(None))):
        since = {k: ran_node[k] for k in ("saturation", "ki") if k in ran_node}  # defaults that changed since
        algo["multiplier"] = {"kind": ran_node["kind"], **since, **(node or {})}
    return {**author, "algo": algo}
