"""deploy.weights=feasible: the linear programme over the snapshots' measured values against
hand-solved cases, the weighted per-episode draw, and a run that deploys, records and reloads the
chosen mixture (mixture_selection.py)."""

import json

import pytest
import torch
import yaml
from helpers.policies import fork_mixture
from helpers.runs import eval_result, tiny

from cmdp_rl import keys, load_config, train
from cmdp_rl.cli import evaluate as evaluate_cli
from cmdp_rl.deploy.mixture import mixture_actor
from cmdp_rl.deploy.selection import MemberValue, feasible_weights
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.run.rundir import load_trained
from lab.studies.fork_policy import weights_of


def _member(ret: float, costs: list[float], se: list[float] | None = None) -> MemberValue:
    return MemberValue(ret, tuple(costs), tuple(se or [0.0] * len(costs)), 100)


def test_one_budget_mixes_the_best_member_on_each_side_of_it():
    # Reach1D's shape at d = 0.5: cross (1.8 at cost 1), approach the wall (0.4), stand still (-0.1).
    members = [_member(1.8, [1.0]), _member(-0.1, [0.0]), _member(0.4, [0.0]), _member(1.0, [0.9])]
    w, feasible = feasible_weights(members, [0.5], margin=0.0)
    # On the segment cross--approach: 0.5 * 1.8 + 0.5 * 0.4 = 1.1; the member at (1.0, 0.9) lies below it.
    assert feasible and w == pytest.approx([0.5, 0.0, 0.5, 0.0], abs=1e-9)


def test_the_margin_takes_each_cost_standard_errors_high():
    members = [_member(1.8, [1.0], [0.05]), _member(0.4, [0.0], [0.0])]
    w, feasible = feasible_weights(members, [0.5], margin=2.0)
    # w * (1.0 + 2 * 0.05) = 0.5 -> w = 0.5 / 1.1
    assert feasible and w[0] == pytest.approx(0.5 / 1.1) and sum(w) == pytest.approx(1.0)


def test_two_budgets_hand_solved():
    # Costs [a, b] at budgets [0.3, 0.15]: A (1.0, [0.6, 0.0]), B (0.8, [0.0, 0.3]), C (0.5, [0, 0]).
    # Both bind at wA = 0.5, wB = 0.5, wC = 0 (costs [0.3, 0.15]), return 0.9; no other vertex is
    # better (A with C: wA <= 0.5 gives 0.75; B with C: wB <= 0.5 gives 0.65).
    members = [_member(1.0, [0.6, 0.0]), _member(0.8, [0.0, 0.3]), _member(0.5, [0.0, 0.0])]
    w, feasible = feasible_weights(members, [0.3, 0.15], margin=0.0)
    assert feasible and w == pytest.approx([0.5, 0.5, 0.0], abs=1e-9)


def test_no_mixture_within_budget_deploys_the_least_violating_member():
    members = [_member(2.0, [3.0]), _member(1.0, [1.5]), _member(0.5, [1.5])]  # every member over d = 1
    w, feasible = feasible_weights(members, [1.0], margin=0.0)
    assert not feasible and w == [0.0, 1.0, 0.0]  # ties on violation: the higher return


def test_weighted_draws_per_episode_and_zero_weights_never_drawn():
    env, agent, actors = fork_mixture(members=3)
    agent.actor = mixture_actor(actors[:2], [0.8, 0.2])
    assert weights_of(agent.actor) == pytest.approx([0.8, 0.2])
    torch.manual_seed(0)
    batch = Collector(env, agent, 512, seed=0).collect()
    member = batch.get((keys.NEXT, keys.MIXTURE_MEMBER)).squeeze(-1)
    starts = member[batch.get(keys.IS_INIT).squeeze(-1)]
    share = (starts == 0).double().mean().item()
    n = starts.numel()
    assert n > 400 and abs(share - 0.8) < 4 * (0.8 * 0.2 / n) ** 0.5  # 4 standard errors


@pytest.fixture(scope="module")
def feasible_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("feasible") / "run"
    cfg = tiny(
        total_steps=256,
        deploy={"policy": "mixture", "window": 0.5, "snapshots": 4, "weights": "feasible", "episodes": 10},
        eval_deterministic=False,
    )
    lines = []
    return out, train(load_config(cfg), out, echo=lines.append), lines


def test_the_run_deploys_records_and_reloads_the_chosen_mixture(feasible_run, tmp_path):
    out, result, lines = feasible_run
    values = result["mixture_member_values"]
    assert len(values) == len(result["mixture_iterations"]) == 4 and all(v["episodes"] == 10 for v in values)
    chosen = dict((int(it), w) for it, w in result["mixture_deployed"])
    assert sum(chosen.values()) == pytest.approx(1.0) and set(chosen) <= set(result["mixture_iterations"])
    margin = yaml.safe_load((out / "config.yaml").read_text())["deploy"]["margin"]
    if result["mixture_feasible"]:  # the chosen weights hold the budget on the values they were chosen on
        upper = sum(
            w * (v["episode_cost"][0] + margin * v["cost_se"][0])
            for it, v in zip(result["mixture_iterations"], values)
            for w in [chosen.get(it, 0.0)]
        )
        assert upper <= result["cost_limit"] + 1e-9
    assert any(line.startswith("mixture: ") for line in lines)
    state = torch.load(out / "checkpoint.pt", weights_only=True)
    assert state["members"][0]["policy_mixture"]["weights"] is not None
    trained = load_trained(out)
    assert weights_of(trained.agent.actor) == pytest.approx([w for w in chosen.values()])
    trained.env.close()
    e = tmp_path / "e.json"
    assert evaluate_cli.main([f"run={out}", f"output={e}"]) == 0
    got = json.loads(e.read_text())
    names = [f"episode_{m}" for m in ("return", "cost", "length")]
    assert {k: got[k] for k in names} == {k: eval_result(out)[k] for k in names}  # same mixture, same episodes


def test_a_gym_reach1d_run_values_its_snapshots_on_the_torch_twin():
    """The valuation of env=reach1d (gymnasium backend) steps the batched twin, the same CMDP to
    the last bit: the members' values equal those of the same run on env.backend=torch."""
    from cmdp_rl.deploy.selection import value_members
    from cmdp_rl.envs import make_env
    from cmdp_rl.policies import make_agent

    cfgs = [load_config(tiny(env={"backend": b}, deploy={"episodes": 12})) for b in ("gym", "torch")]
    assert cfgs[0].env.valuation_options().backend == "torch" and cfgs[0].env.backend == "gym"
    torch.manual_seed(0)
    env = make_env(cfgs[1].env, 2)
    agents = [make_agent(cfgs[1].policy, env) for _ in range(2)]
    actors = [a.actor for a in agents]
    values = [value_members(actors, agents[0], cfg, 1) for cfg in cfgs]
    assert values[0] == values[1] and values[0][0] != values[0][1]
    assert all(v.episodes >= 12 for v in values[0])
