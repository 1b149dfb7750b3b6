"""Several constraints end to end: an env reporting K = 2 costs through the collector, the cost
critic and GAE, the scalers, the multipliers, metrics.csv, eval.json and the plots.

The env is a toy (tests/helpers/cost_envs.py: TwoCost, registered with gymnasium, used through ``env=gym``), so
every number below can be worked out by hand."""

import csv
import json

import pytest
import torch
from helpers.cli import train_py
from helpers.cost_envs import TWO_COST_ID, TWO_COST_NAMES, two_cost_cfg, two_cost_env
from helpers.tolerance import Tolerance, assert_close
from tensordict import TensorDict

from cmdp_rl import keys, load_config, train
from cmdp_rl.algos import make_algo
from cmdp_rl.algos.multiplier import DualAscent, Multipliers
from cmdp_rl.config.validation import ConfigError
from cmdp_rl.policies import make_agent
from cmdp_rl.policies.mlp import PolicyConfig
from cmdp_rl.report.metrics import columns
from cmdp_rl.report.plot import group_runs
from cmdp_rl.report.plot import main as plot_main
from cmdp_rl.rollout.advantages import TwinGAE
from cmdp_rl.rollout.collector import Collector, finished_episodes
from cmdp_rl.rollout.normalization import ReturnScaler
from cmdp_rl.run.migrations import migrate


def test_the_env_names_its_costs_or_they_are_numbered():
    assert two_cost_env().cost_names == TWO_COST_NAMES and two_cost_env().num_costs == 2
    unnamed = two_cost_env(named=False)  # K from one probe step of a throwaway env
    assert unnamed.num_costs == 2 and unnamed.cost_names == ("cost_0", "cost_1")


def test_collector_keeps_one_episode_sum_and_one_previous_cost_per_constraint():
    env = two_cost_env(length=3)
    agent = make_agent(PolicyConfig(include_prev_cost=True), env)
    collector = Collector(env, agent, rollout_steps=7, seed=0)
    batch = collector.collect()
    nxt = batch.get(keys.NEXT)
    t = torch.tensor([1.0, 2, 3, 1, 2, 3, 1])  # the step within its episode, for both envs
    assert torch.equal(nxt.get(keys.COST), torch.stack([torch.ones(7), t], -1).expand(2, 7, 2))
    # Running sums: hazard_a counts steps, hazard_b adds t; both restart after step 3.
    running = torch.tensor([[1.0, 1], [2, 3], [3, 6], [1, 1], [2, 3], [3, 6], [1, 1]])
    assert torch.equal(nxt.get(keys.EPISODE_COST), running.expand(2, 7, 2))
    eps = finished_episodes(batch)
    assert eps["cost"].tolist() == [[3.0, 6.0]] * 4 and eps["length"].tolist() == [3.0] * 4
    # Totals per constraint: 7 steps x 2 envs of cost 1; t summed, 13 per env.
    assert collector.total_costs == [14.0, 26.0]
    # The previous step's cost vector, zero on each episode's first step.
    prev = torch.tensor([[0.0, 0], [1, 1], [1, 2], [0, 0], [1, 1], [1, 2], [0, 0]])
    assert torch.equal(batch.get(keys.PREV_COST), prev.expand(2, 7, 2))
    # The cost critic values both constraints.
    assert agent.value("cost", {keys.OBS: batch.get(keys.OBS)[:, 0], keys.PREV_COST: prev[:1].expand(2, 2)}).shape == (
        2,
        2,
    )
    # A checkpoint keeps the per-constraint totals and running sums.
    again = Collector(two_cost_env(length=3), agent, rollout_steps=7, seed=0)
    again.load_state_dict(collector.state_dict())
    assert again.total_costs == [14.0, 26.0] and torch.equal(again._ep_cost, collector._ep_cost)


# torchrl's GAE sums each trajectory's discounted TD errors by a 1-D convolution over the batch's trajectories, K
# times as many with K cost columns: for another batch the convolution may pick a kernel that sums a step's at most
# 5 terms (5-step episodes here) in another order, a few float32 roundings (6e-8 each) of the terms' absolute sum
# (at most about 15 here) apart. Measured equal under every make test-cpus setting.
COLUMNS = Tolerance("each constraint's GAE, K columns or one", rel=1e-6, abs=1e-6)


@pytest.mark.cpu_kernels
def test_each_constraints_gae_is_the_gae_of_that_cost_alone():
    torch.manual_seed(0)
    env = two_cost_env(num_envs=3, length=5, mode="learn")
    agent = make_agent(PolicyConfig(), env)
    batch = Collector(env, agent, rollout_steps=64, seed=1).collect()
    # Make the two costs differ everywhere: the second is a scrambled, scaled copy of the first.
    cost = batch.get((keys.NEXT, keys.COST))
    cost[..., 1] = torch.rand(cost.shape[:2]) * 3
    gae = TwinGAE(gamma=0.99, cost_gamma=0.97, lmbda=0.95)
    gae(batch, agent)
    adv, target = batch.get(keys.COST_ADVANTAGE), batch.get(keys.COST_VALUE_TARGET)
    assert adv.shape == (3, 64, 2)
    nxt = batch.get(keys.NEXT)
    for k in range(2):
        alone = TensorDict(
            {
                keys.COST_VALUE: batch.get(keys.COST_VALUE)[..., k : k + 1],
                (keys.NEXT, keys.COST_VALUE): nxt.get(keys.COST_VALUE)[..., k : k + 1],
                (keys.NEXT, keys.COST): nxt.get(keys.COST)[..., k : k + 1],
                (keys.NEXT, keys.DONE): nxt.get(keys.DONE),
                (keys.NEXT, keys.TERMINATED): nxt.get(keys.TERMINATED),
            },
            batch_size=batch.shape,
        )
        gae.cost(alone)  # the K = 1 path
        assert_close(alone.get(keys.COST_ADVANTAGE), adv[..., k : k + 1], COLUMNS, f"advantage {k}")
        assert_close(alone.get(keys.COST_VALUE_TARGET), target[..., k : k + 1], COLUMNS, f"value target {k}")
    assert not torch.equal(adv[..., 0], adv[..., 1])


def test_cost_scaling_is_per_constraint():
    scaler = ReturnScaler(num_envs=2, gamma=0.9, channels=2)
    x = torch.rand(2, 50, 1)
    signal = torch.cat([x, 100 * x], -1)  # the second cost is the first in other units
    scaler.update(signal, torch.zeros(2, 50, 1, dtype=torch.bool))
    scaled = scaler.scale(signal)
    assert torch.allclose(scaled[..., 0], scaled[..., 1], rtol=1e-4)


def test_policy_advantage_sums_over_constraints_with_todays_normalisation():
    env = two_cost_env()
    batch = TensorDict(
        {
            keys.ADVANTAGE: torch.tensor([[[1.0], [2.0]]]),
            keys.COST_ADVANTAGE: torch.tensor([[[1.0, 10.0], [-1.0, 0.5]]]),
        },
        batch_size=[1, 2],
    )
    cfg = load_config(two_cost_cfg()).algo
    lag = make_algo(cfg, make_agent(PolicyConfig(), env))
    for controller, value in zip(lag.multiplier.controllers, (0.5, 2.0)):
        controller.value = value
    # (A_r - 0.5 A_c,a - 2 A_c,b) / (1 + 2.5)
    expected = torch.tensor([[[(1 - 0.5 - 20) / 3.5], [(2 + 0.5 - 1) / 3.5]]])
    assert torch.allclose(lag.policy_advantage(batch), expected)
    assert lag.lagrange_multiplier == [0.5, 2.0]
    penalty = make_algo(
        load_config(two_cost_cfg(algo={"name": "penalty", "penalty": [1.0, 0.1]})).algo, make_agent(PolicyConfig(), env)
    )
    assert torch.allclose(penalty.policy_advantage(batch), torch.tensor([[[1 - 1 - 1.0], [2 + 1 - 0.05]]]))
    one = make_algo(
        load_config(two_cost_cfg(algo={"name": "penalty", "penalty": 3.0})).algo, make_agent(PolicyConfig(), env)
    )
    assert one.lagrange_multiplier == [3.0, 3.0]


def test_one_multiplier_is_a_list_of_one_and_the_single_constraint_format_migrates():
    """One state per constraint, K = 1 included; format 2 saved one constraint's as the bare
    controller state, which cmdp_rl.run.migrations puts under ``constraints`` (and which then loads)."""
    single = Multipliers(lambda d: DualAscent(d, lr=0.1), [1.0])
    single.update([3.0])
    assert single.state_dict() == {"constraints": [{"value": pytest.approx(0.2)}]}
    old = {"format": 2, "algo": "ppo_lag", "algo_state": {"multiplier": {"value": 0.2}}}
    restored = Multipliers(lambda d: DualAscent(d, lr=0.1), [1.0])
    restored.load_state_dict(migrate(old)["members"][0]["algo_state"]["multiplier"])
    assert restored.values == pytest.approx(single.values)
    double = Multipliers(lambda d: DualAscent(d, lr=0.1), [1.0, 5.0])
    assert double.update([3.0, 3.0]) == [pytest.approx(0.2), 0.0]
    other = Multipliers(lambda d: DualAscent(d, lr=0.1), [1.0, 5.0])
    other.load_state_dict(double.state_dict())
    assert other.values == double.values


@pytest.mark.parametrize(
    ("algo", "message"),
    [
        (
            {"name": "ppo_lag", "cost_limit": [1.0, 2.0, 3.0]},
            "algo.cost_limit must be a number or a list of 2 numbers, one per cost of the env (hazard_a, hazard_b), "
            "got [1.0, 2.0, 3.0]",
        ),
        ({"name": "ppo", "cost_limit": [1.0]}, "algo.cost_limit must be a number or a list of 2 numbers"),
        ({"name": "penalty", "penalty": [1.0, 2.0, 3.0]}, "algo.penalty must be a number or a list of 2 numbers"),
        (
            {"name": "cpo", "cost_limit": 1.0},
            "algo must be penalty, pid_lag, ppo, ppo_lag, sac, sac_lag, saute, td3, td3_lag or trpo_lag for an env with 2 costs "
            "(hazard_a, hazard_b): cpo's closed-form dual handles one constraint",
        ),
        *(
            (
                {"name": name},
                f"algo must be penalty, pid_lag, ppo, ppo_lag, sac, sac_lag, saute, td3, td3_lag or trpo_lag for an env with 2 costs "
                f"(hazard_a, hazard_b): {reason}, got '{name}'",
            )
            for name, reason in (
                ("pcpo", "pcpo projects onto one linearised constraint"),
                ("crpo", "crpo's step switches on one constraint's slack"),
                ("focops", "focops has one cost multiplier nu"),
                ("cup", "cup has one cost multiplier nu"),
            )
        ),
    ],
)
def test_per_constraint_options_of_the_wrong_length_are_config_errors(tmp_path, quiet, algo, message):
    cfg = two_cost_cfg()
    cfg["algo"] = algo
    with pytest.raises(
        ConfigError,
        match="^"
        + message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]").replace(".", r"\."),
    ):
        train(load_config(cfg), tmp_path / "run", echo=quiet)
    assert not (tmp_path / "run").exists()  # stopped before anything was written


def test_metrics_columns_for_two_constraints():
    cols = columns(("loss_pi",), TWO_COST_NAMES)
    assert cols[:12] == [
        "iteration",
        "step",
        "episode_return",
        "episode_cost/hazard_a",
        "episode_cost/hazard_b",
        "episode_length",
        "episodes",
        "lagrange_multiplier/hazard_a",
        "lagrange_multiplier/hazard_b",
        "cost_limit/hazard_a",
        "cost_limit/hazard_b",
        "sps",
    ]
    assert cols[-7:] == [
        "cost_rate/hazard_a",
        "cost_rate/hazard_b",
        "normalized_return",
        "normalized_violation/hazard_a",
        "normalized_violation/hazard_b",
        "normalized_cost_rate/hazard_a",
        "normalized_cost_rate/hazard_b",
    ]
    assert columns(("loss_pi",))[3:8] == [
        "episode_cost",
        "episode_length",
        "episodes",
        "lagrange_multiplier",
        "cost_limit",
    ]


def read_rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_ppo_lag_on_two_costs_moves_each_multiplier_on_its_own_constraint(tmp_path, quiet):
    # hazard_a: paid for every positive action (about half of a random policy's), budget 0.5 per
    # 4-step episode: over budget, its lambda rises. hazard_b: never paid, budget 1: it stays at 0.
    out = tmp_path / "run"
    # multiplier.scale none: each multiplier steps in its cost's own units, as the checks below compute
    result = train(load_config(two_cost_cfg(algo={"multiplier": {"scale": "none"}})), out, echo=quiet)
    rows = read_rows(out / "metrics.csv")
    assert len(rows) == 6 and list(rows[0])[:5] == [
        "iteration",
        "step",
        "episode_return",
        "episode_cost/hazard_a",
        "episode_cost/hazard_b",
    ]
    lam_a = prev_a = 0.0
    for row in rows:
        j_a, j_b = float(row["episode_cost/hazard_a"]), float(row["episode_cost/hazard_b"])
        assert j_b == 0.0 and float(row["lagrange_multiplier/hazard_b"]) == 0.0
        # Episodes of 4 steps end in every 16-step batch: lambda_a moves on this batch's J_c,a alone.
        lam_a = max(0.0, lam_a + 0.5 * (j_a - 0.5))
        assert float(row["lagrange_multiplier/hazard_a"]) == pytest.approx(lam_a, rel=1e-6)
        assert float(row["cost_limit/hazard_a"]) == 0.5 and float(row["cost_limit/hazard_b"]) == 1.0
        assert float(row["cost_rate/hazard_a"]) >= 0.0 and float(row["cost_rate/hazard_b"]) == 0.0
        prev_a = max(prev_a, lam_a)
    assert float(rows[0]["episode_cost/hazard_a"]) > 0.5 and prev_a > 0.0  # it was over budget and lambda rose
    written = json.loads((out / "eval.json").read_text())
    assert written == result
    for key in (
        "episode_cost/hazard_a",
        "episode_cost_std/hazard_a",
        "episode_cost_max/hazard_b",
        "cost_limit/hazard_a",
        "cost_rate/hazard_b",
        "normalized_violation/hazard_a",
    ):
        assert key in written
    assert "episode_cost" not in written and written["cost_limit/hazard_b"] == 1.0
    assert written["episode_cost/hazard_b"] == 0.0


@pytest.mark.parametrize(
    "policy",
    [
        {"name": "lstm", "hidden_size": 8, "head_sizes": [8]},
        {"name": "transformer", "window": 3, "width": 8, "heads": 2, "layers": 1, "feedforward": 8, "head_sizes": [8]},
    ],
)
def test_memory_policies_read_the_cost_vector(tmp_path, quiet, policy):
    cfg = two_cost_cfg(policy=policy, total_steps=2 * 32, algo={"name": "pid_lag"})
    train(load_config(cfg), tmp_path / "run", echo=quiet)
    rows = read_rows(tmp_path / "run" / "metrics.csv")
    assert len(rows) == 2 and float(rows[-1]["lagrange_multiplier/hazard_b"]) == 0.0


def test_plots_draw_a_panel_per_constraint(tmp_path, quiet):
    train(load_config(two_cost_cfg(total_steps=2 * 32)), tmp_path / "run", echo=quiet)
    (curve,) = group_runs([tmp_path / "run"])
    assert [p for p, _ in curve.panels] == [
        "episode_return",
        "episode_cost/hazard_a",
        "episode_cost/hazard_b",
        "lagrange_multiplier/hazard_a",
        "lagrange_multiplier/hazard_b",
    ]
    assert curve.cost_limits == {"episode_cost/hazard_a": 0.5, "episode_cost/hazard_b": 1.0}
    out = tmp_path / "curves.png"
    assert plot_main([str(tmp_path / "run"), "-o", str(out)]) == 0 and out.read_bytes()[:4] == b"\x89PNG"


def test_evaluate_script_prints_a_cost_line_per_constraint(tmp_path, quiet, capsys):
    train(load_config(two_cost_cfg(total_steps=2 * 32)), tmp_path / "run", echo=quiet)
    from cmdp_rl.cli import evaluate as script

    assert script.main([f"run={tmp_path / 'run'}", "episodes=2", f"output={tmp_path / 'e.json'}"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.strip().startswith("cost/hazard_a") and line.endswith("(limit 0.5)") for line in lines)
    assert any(
        line.split()[:4] == ["cost/hazard_b", "0.00", "±", "0.00"] and line.endswith("(limit 1.0)") for line in lines
    )
    assert json.loads((tmp_path / "e.json").read_text())["episode_cost/hazard_b"] == 0.0


def test_train_cli_stops_on_a_wrong_length_budget_with_one_line(tmp_path):
    # The toy env is imported through env.id=<module>:<id>.
    proc = train_py(
        "env=gym",
        f"env.id=helpers.cost_envs:{TWO_COST_ID}",
        "algo.cost_limit=[1,2,3]",
        f"hydra.run.dir={tmp_path / 'run'}",
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr + proc.stdout
    assert proc.stderr.strip().splitlines()[-1] == (
        "config error: algo.cost_limit must be a number or a list of 2 numbers, one per cost of the env "
        "(hazard_a, hazard_b), got [1.0, 2.0, 3.0]"
    )
    assert not (tmp_path / "run" / "metrics.csv").exists()


def test_trpo_lag_on_two_costs_moves_each_multiplier_on_its_own_constraint(tmp_path, quiet):
    # As ppo_lag above: hazard_a over its budget 0.5, its lambda rises by dual ascent on this
    # batch's J_c,a alone; hazard_b never paid, its lambda stays 0.
    out = tmp_path / "run"
    cfg = two_cost_cfg()
    cfg["algo"] = {
        "name": "trpo_lag",
        "critic_minibatches": 2,
        "cost_limit": [0.5, 1.0],
        "multiplier": {"kind": "dual", "lr": 0.5, "scale": "none"},  # the dual ascent computed by hand below
        "advantage_scale": "raw",
    }
    result = train(load_config(cfg), out, echo=quiet)
    rows = read_rows(out / "metrics.csv")
    lam_a = 0.0
    for row in rows:
        lam_a = max(0.0, lam_a + 0.5 * (float(row["episode_cost/hazard_a"]) - 0.5))
        assert float(row["lagrange_multiplier/hazard_a"]) == pytest.approx(lam_a, rel=1e-6)
        assert float(row["lagrange_multiplier/hazard_b"]) == 0.0
    assert float(rows[0]["episode_cost/hazard_a"]) > 0.5 and float(rows[0]["lagrange_multiplier/hazard_a"]) > 0.0
    assert result["cost_limit/hazard_a"] == 0.5


def test_eval_intervals_and_summary_per_constraint(tmp_path):
    lines = []
    result = train(load_config(two_cost_cfg(total_steps=2 * 32, eval_episodes=6)), tmp_path / "run", echo=lines.append)
    # One return interval; each constraint its own cost interval and violation count against its budget.
    assert len(result["episode_return_ci95"]) == 2 and "episode_cost_ci95" not in result
    assert result["violations/hazard_b"] == 0 and result["violation_rate/hazard_b"] == 0.0
    assert result["intervals/hazard_a"]["violation"] == "episode cost > 0.5"
    assert result["intervals/hazard_b"]["violation"] == "episode cost > 1"
    # hazard_a: an episode violates with any positive action (cost >= 1 > 0.5).
    assert result["violation_rate/hazard_a"] == result["violations/hazard_a"] / 6
    assert (result["violations/hazard_a"] > 0) == (result["episode_cost_max/hazard_a"] > 0.5)
    summary = [line for line in lines if "against budget" in line]
    assert [line.split()[0] for line in summary] == ["hazard_a", "hazard_b"]
    assert summary[1].strip() == "hazard_b 0.00 ± 0.00 against budget 1: within budget"
    assert any(line.strip().startswith("hazard_b: violations 0/6 episodes (cost > 1)") for line in lines)
