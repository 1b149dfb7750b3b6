"""Run directories saved before ``algo.multiplier`` was one node (flat ``lambda_lr``, ``lambda_init``,
``multiplier: dual``, ``kp``, ...; cmdp_rl/run/migrations.py ``multiplier_node``) still load, evaluate and
resume, and continue exactly as the run would have."""

import copy

import pytest
import yaml
from helpers.resume import assert_same_run
from helpers.runs import tiny

from cmdp_rl import load, load_config, train
from cmdp_rl.algos.multiplier import PIDLagrangian
from cmdp_rl.algos.multiplier_options import multiplier_options
from cmdp_rl.cli import evaluate as evaluate_cli
from cmdp_rl.run.checkpoint import load_checkpoint, save_checkpoint
from cmdp_rl.run.migrations import recorded_defaults, saved_config_defaults, saved_config_nodes
from cmdp_rl.run.resume import resume_config

# Every term of the PID controller carries state (the integral, both EMAs, the delayed costs), so a
# resume that rebuilt another controller, or these gains wrongly, would move the numbers.
GAINS = {"kp": 1.0, "ki": 0.5, "kd": 0.5, "p_ema_alpha": 0.5, "d_ema_alpha": 0.5, "d_delay": 2}
NODE = {"kind": "pid", "init": 0.1, "scale": "none", "max": 4.0, **GAINS}
# The same options as pid_lag's config wrote them before the node: no kind (pid_lag was always PID).
FLAT = {"lambda_init": 0.1, "lambda_scale": "none", "lambda_max": 4.0, **GAINS}


def _as_before_the_node(run) -> None:
    """Rewrite a run's saved configs (config.yaml and the checkpoint's) into the flat layout."""

    def flat(config: dict) -> dict:
        config = copy.deepcopy(config)
        node = config["algo"].pop("multiplier")
        assert node["kind"] == "pid" and node["kp"] == 1.0  # the run really had these
        config["algo"].update(FLAT)
        return config

    (run / "config.yaml").write_text(yaml.safe_dump(flat(yaml.safe_load((run / "config.yaml").read_text()))))
    state = load_checkpoint(run / "checkpoint.pt")
    members = [{**m, "config": flat(m["config"])} for m in state["members"]]  # format 4: configs per member
    save_checkpoint(run / "checkpoint.pt", {**state, "members": members})


def test_an_old_pid_lag_run_evaluates_and_resumes_as_the_run_continued(tmp_path, quiet):
    cfg = tiny(algo={"name": "pid_lag", "multiplier": NODE})
    long, short = tmp_path / "long", tmp_path / "short"
    train(load_config(cfg), long, echo=quiet)
    train(load_config({**cfg, "total_steps": 4 * 32}), short, echo=quiet)
    _as_before_the_node(short)
    assert "multiplier" not in yaml.safe_load((short / "config.yaml").read_text())["algo"]

    action, _ = load(short).predict([0.3, 0.0])  # the deployed policy from the old directory (position, velocity)
    assert action.shape == (1,)
    assert evaluate_cli.main([f"run={short}", f"output={tmp_path / 'again.json'}"]) == 0

    resumed = resume_config(short, {"total_steps": 7 * 32}, ["total_steps"])
    assert resumed.algo.multiplier.kind == "pid" and resumed.algo.multiplier.max == 4.0
    train(resumed, echo=quiet)
    assert_same_run(long, short)


@pytest.mark.parametrize(
    "old, node",
    [
        # ppo_lag as the tiny tests and old runs wrote it (anneal_lambda_lr is gone).
        (
            {"name": "ppo_lag", "lambda_lr": 0.5, "lambda_init": 0.0, "anneal_lambda_lr": False, "multiplier": "dual"},
            {"kind": "dual", "lr": 0.5, "init": 0.0},
        ),
        # Off-policy: pid was a value of `multiplier`; every flat name has its field, and the node keeps its kind's
        # (the other kinds' options, which pid never read, are dropped).
        (
            {"name": "sac_lag", "multiplier": "pid", "lambda_lr": 0.01, "kp": 0.5, "lambda_tau": 0.2, "lambda_nu": 0.3},
            {"kind": "pid", "kp": 0.5},
        ),
        # A node saved with every kind's fields (before each kind had its own options) keeps its kind's.
        (
            {
                "name": "ppo_lag",
                "multiplier": {"kind": "dual", "lr": 0.1, "tau": 0.1, "nu": 0.0, "kp": 2.0, "max": 3.0},
            },
            {"kind": "dual", "lr": 0.1, "max": 3.0},
        ),
        # FOCOPS's and CUP's nu: the same node (FOCOPS's clamp is its max), with the kind of its day.
        (
            {"name": "focops", "nu_init": 0.2, "nu_lr": 0.5, "nu_max": 3.0, "nu_scale": "none"},
            {"kind": "dual", "init": 0.2, "lr": 0.5, "max": 3.0, "scale": "none"},
        ),
        # pid_lag without any multiplier option still is PID.
        ({"name": "pid_lag"}, {"kind": "pid"}),
        # An algorithm without a multiplier keeps its options, the penalty's included.
        ({"name": "ppo", "lr": 1e-3}, None),
    ],
)
def test_flat_options_move_into_the_node(old, node):
    algo = saved_config_nodes({"algo": old, "mixture_weights": "feasible"})["algo"]
    assert algo.get("multiplier") == node
    flat = ("lambda_", "nu_", "kp", "multiplier")
    kept = {k: v for k, v in old.items() if node is None or not k.startswith(flat)}
    assert {k: v for k, v in algo.items() if k != "multiplier"} == {
        k: v for k, v in kept.items() if k != "anneal_lambda_lr"
    }
    built = load_config(saved_config_defaults({"algo": old, "mixture_weights": "feasible"})).algo
    if node is not None:
        assert {k: getattr(built.multiplier, k) for k in node} == node


def test_a_config_from_before_mixture_weights_ran_with_the_raw_violation():
    """Such a config ran with lambda_scale none (the default of its day); it lands in the node."""
    cfg = load_config(saved_config_defaults({"algo": {"name": "ppo_lag", "lambda_lr": 0.2}}))
    assert (cfg.algo.multiplier.kind, cfg.algo.multiplier.scale, cfg.algo.multiplier.lr) == ("dual", "none", 0.2)
    assert cfg.algo.advantage_scale == "raw"  # the only scale of its day (ppo_lag's default is standardized now)
    assert load_config(saved_config_defaults({"algo": {"name": "focops"}})).algo.multiplier.scale == "none"


def test_a_log_dual_saved_before_its_saturation_existed_keeps_the_step_it_ran_with():
    """The log dual's step was in proportion to the violation up to J_c = 2d (saturation 1) before the option."""
    saved = {"algo": {"name": "ppo_lag", "multiplier": {"kind": "log", "lr": 2.0, "init": 0.01}}, "deploy": {}}
    assert load_config(saved_config_defaults(saved)).algo.multiplier.saturation == 1.0
    saved["algo"]["multiplier"]["saturation"] = 0.25  # recorded since: kept
    assert load_config(saved_config_defaults(saved)).algo.multiplier.saturation == 0.25
    assert load_config({"algo": {"name": "ppo_lag"}}).algo.multiplier.saturation == 0.25  # today's default
    # a population's config names what its author gave; its members' records say what ran
    author = {"algo": {"name": "ppo_lag", "multiplier": {"lr": 1.0}}}
    ran = recorded_defaults(author, {"algo": {"name": "ppo_lag", "multiplier": {"kind": "log"}}, "deploy": {}})
    assert ran["algo"]["multiplier"] == {"kind": "log", "saturation": 1.0, "lr": 1.0}
    pid = {"algo": {"name": "pid_lag", "advantage_scale": "raw", "multiplier": {"kind": "pid", "ki": 0.1}}}
    ran = recorded_defaults({"algo": {"name": "pid_lag"}}, {**pid, "deploy": {}})  # ki's default was 0.1 then
    assert ran["algo"]["multiplier"] == {"kind": "pid", "ki": 0.1} and ran["algo"]["advantage_scale"] == "raw"


def test_a_population_grid_over_flat_options_moves_into_the_node():
    raw = {"algo": {"name": "pid_lag", "kp": 1.0}, "population": {"grid": {"algo": {"ki": [0.1, 0.2], "lr": [1e-3]}}}}
    out = saved_config_nodes(raw)
    assert out["algo"] == {"name": "pid_lag", "multiplier": {"kind": "pid", "kp": 1.0}}
    assert out["population"]["grid"]["algo"] == {"lr": [1e-3], "multiplier": {"ki": [0.1, 0.2]}}
    current = {"algo": {"name": "ppo_lag"}, "population": {"grid": {"algo": {"multiplier": {"lr": [0.1, 0.2]}}}}}
    assert saved_config_nodes(current) == current  # a grid over the node itself is left as it is


def test_a_moved_config_keeps_its_node_values_over_flat_defaults():
    """A population's config, moved when read, then given the defaults of before mixture_weights
    (the stacked layout's resume): the flat default lands in the node without replacing its values."""
    moved = saved_config_nodes({"algo": {"name": "ppo_lag", "lambda_lr": 0.5}})
    cfg = load_config(saved_config_defaults(moved))
    assert (cfg.algo.multiplier.kind, cfg.algo.multiplier.lr, cfg.algo.multiplier.scale) == ("dual", 0.5, "none")
    given = saved_config_defaults({"algo": {"name": "ppo_lag", "multiplier": {"kind": "dual", "scale": "budget"}}})
    assert load_config(given).algo.multiplier.scale == "budget"


def test_focops_old_nu_state_loads_into_the_node_and_continues_the_same():
    """FOCOPS's nu was PID's integral alone clamped at nu_max (multiplier.PIDLagrangian with kp = kd = 0);
    the node's dual ascent with max gives the same numbers, and the old saved state loads into it."""
    costs = [3.0, 2.5, 0.2, 0.0, 4.0, 1.0, 0.9]
    old = PIDLagrangian(0.5, kp=0.0, ki=0.3, kd=0.0, init=0.1, lambda_max=1.2, scale=0.5)
    new = multiplier_options("dual", lr=0.3, init=0.1, max=1.2, scale="budget").build(0.5)
    assert [old.update(c) for c in costs[:4]] == [new.update(c) for c in costs[:4]]
    resumed = multiplier_options("dual", lr=0.3, init=0.1, max=1.2, scale="budget").build(0.5)
    resumed.load_state_dict(old.state_dict())  # an old checkpoint's "multiplier"
    assert [old.update(c) for c in costs[4:]] == [resumed.update(c) for c in costs[4:]]
