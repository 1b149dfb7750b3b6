"""deploy.policy=mixture: one member drawn per episode and kept to its end, uniform draws, the
snapshot schedule, and the deployed mixture used alike by the run's evaluation, its checkpoint
(loaded with weights_only=True), eval.json and evaluate.py."""

import io
import json

import numpy as np
import pytest
import torch
from helpers.policies import fork_mixture
from helpers.runs import eval_result, tiny

from cmdp_rl import keys, load_config, train
from cmdp_rl.cli import evaluate as evaluate_cli  # noqa: E402  (the command's main, in-process)
from cmdp_rl.config.run_config import ConfigError
from cmdp_rl.deploy.mixture import IterateSnapshots
from cmdp_rl.rollout.collector import Collector
from cmdp_rl.run.rundir import load_trained
from lab.studies.fork_policy import members_of


def test_one_member_per_episode_drawn_uniformly():
    env, agent, actors = fork_mixture()
    torch.manual_seed(0)
    batch = Collector(env, agent, 512, seed=0).collect()
    member = batch.get((keys.NEXT, keys.MIXTURE_MEMBER)).squeeze(-1)  # [N, T]: the member each step acted with
    is_init = batch.get(keys.IS_INIT).squeeze(-1)
    # Within an episode the member never changes (from the second step on it is the previous one's).
    assert torch.equal(member[:, 1:][~is_init[:, 1:]], member[:, :-1][~is_init[:, 1:]])
    # Each step's action distribution is its member's own.
    obs, chosen = batch.get(keys.OBS)[:, 7], member[:, 7]
    for row in range(obs.shape[0]):
        own = actors[chosen[row]].params({keys.OBS: obs[row : row + 1]})[keys.LOGITS]
        assert torch.allclose(batch.get(keys.LOGITS)[row, 7], own[0])
    # Draws at episode starts: uniform over the 4 members (a chi-square test at the 0.1% level).
    starts = member[is_init]
    counts = torch.bincount(starts, minlength=4).double()
    assert starts.numel() > 400 and counts.min() > 0
    expected = starts.numel() / 4
    assert ((counts - expected) ** 2 / expected).sum() < 16.27  # chi2(3) 99.9% quantile
    # Not per step: the draws change only at episode starts, far fewer times than there are steps.
    changes = (member[:, 1:] != member[:, :-1]).sum()
    assert changes <= is_init[:, 1:].sum() and changes < member.numel() / 4


def test_snapshots_every_stride_ending_at_the_last_and_plain_state():
    snaps = IterateSnapshots(first_iteration=76, iterations=100, size=8)  # window 25 -> stride 4
    assert snaps.stride == 4
    assert [it for it in range(1, 101) if snaps.wants(it)] == [76, 80, 84, 88, 92, 96, 100]
    assert [it for it in range(1, 11) if IterateSnapshots(1, 10, 16).wants(it)] == list(range(1, 11))
    m = torch.nn.Linear(2, 1)
    for it in (1, 2):
        with torch.no_grad():
            m.weight.fill_(float(it))
        snaps.update(m, it)
    buf = io.BytesIO()
    torch.save(snaps.state_dict(), buf)
    buf.seek(0)
    again = IterateSnapshots(1, 1, 1)
    again.load_state_dict(torch.load(buf, weights_only=True))  # plain tensors, ints and lists
    assert again.taken == [1, 2] and [float(s["weight"][0, 0]) for s in again.members] == [1.0, 2.0]


@pytest.fixture(scope="module")
def mixture_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("mixture") / "run"
    cfg = tiny(
        total_steps=256,
        deploy={"policy": "mixture", "window": 0.5, "snapshots": 2, "weights": "uniform"},
        eval_deterministic=False,
    )
    return out, train(load_config(cfg), out, echo=lambda s: None)


def test_mixture_is_what_the_run_evaluates_and_evaluate_py_loads(mixture_run, tmp_path):
    out, result = mixture_run
    # 8 iterations, window 5..8, 2 members: stride 2, iterations 6 and 8.
    assert result["final_policy"] == "mixture" and result["mixture_iterations"] == [6, 8]
    assert result["averaged_iterations"] == 2
    state = torch.load(out / "checkpoint.pt", weights_only=True)  # safe unpickler, no migration
    members = state["members"][0]["policy_mixture"]["members"]
    last = state["members"][0]["algo_state"]["networks"]
    assert all(torch.equal(members[-1][n], last[f"actor.{n}"]) for n in members[-1])  # the last iterate ...
    assert any(not torch.equal(members[0][n], last[f"actor.{n}"]) for n in members[0])  # ... and an earlier one
    trained = load_trained(out)
    deployed = members_of(trained.agent.actor)
    assert len(deployed) == 2 and torch.equal(
        deployed[0].state_dict()[next(iter(members[0]))], members[0][next(iter(members[0]))]
    )
    trained.env.close()
    e = tmp_path / "e.json"
    assert evaluate_cli.main([f"run={out}", f"output={e}"]) == 0
    got = json.loads(e.read_text())
    assert got["final_policy"] == "mixture"
    names = [f"episode_{m}" for m in ("return", "cost", "length")]
    assert {k: got[k] for k in names} == {k: eval_result(out)[k] for k in names}  # same mixture, same episodes


def test_the_command_line_sets_the_mixture():
    from cmdp_rl.config.run_config import compose_config

    cfg = compose_config(["deploy.policy=mixture", "deploy.snapshots=3"])  # as train.py's overrides
    assert (cfg.deploy.policy, cfg.deploy.snapshots, cfg.deploy.weights) == ("mixture", 3, "feasible")


def test_mixture_of_recurrent_actors_is_refused_in_one_line():
    with pytest.raises(ConfigError, match="^deploy.policy must be last or average with policy=lstm"):
        load_config(tiny(deploy={"policy": "mixture"}, policy={"name": "lstm"}))
    with pytest.raises(ConfigError, match=r"^deploy\.snapshots must be in \[1, 64\], got 0$"):
        load_config(tiny(deploy={"policy": "mixture", "snapshots": 0}))


def test_fork_exact_value_of_a_mixture_is_the_mean_of_its_members():
    from lab.studies.fork_policy import mixture_gap

    cfg = load_config({"env": {"name": "fork"}})
    model, best = cfg.env.model(), cfg.env.solve(1.0)
    _, agent, actors = fork_mixture(members=3)
    each = [mixture_gap([a], model, best) for a in actors]
    mixed = mixture_gap(members_of(agent.actor), model, best)
    assert mixed.ret == pytest.approx(np.mean([g.ret for g in each]))
    assert mixed.costs[0] == pytest.approx(np.mean([g.costs[0] for g in each]))


def test_evaluate_py_plots_and_films_the_mixture(mixture_run, tmp_path, capsys):
    pytest.importorskip("moviepy")  # the test extra installs it
    out, _ = mixture_run
    argv = [f"run={out}", f"plot={tmp_path / 'p.png'}", "video=true", "video_episodes=2", "video_steps=6"]
    assert evaluate_cli.main([*argv, f"video_dir={tmp_path / 'v'}", "episodes=2"]) == 0
    assert "deployed policy: mixture" in capsys.readouterr().out
    assert (tmp_path / "p.png").stat().st_size > 0
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == ["policy-episode-0.mp4", "policy-episode-1.mp4"]


def test_a_resumed_run_deploys_the_same_mixture(tmp_path, monkeypatch, quiet):
    from helpers.resume import assert_same_run, crash_then_resume

    # 7 iterations, window 3..7 (5 snapshots, stride 1); checkpoints at 2, 4 and 6, a crash after row 5.
    cfg = tiny(deploy={"policy": "mixture", "window": 0.6, "snapshots": 5, "weights": "uniform"})
    whole, broken = crash_then_resume(cfg, tmp_path, monkeypatch, quiet)
    assert_same_run(whole, broken)
    assert eval_result(broken)["mixture_iterations"] == [3, 4, 5, 6, 7]
    a, b = (torch.load(r / "checkpoint.pt", weights_only=True)["members"][0]["policy_mixture"] for r in (whole, broken))
    assert a["taken"] == b["taken"] and all(
        torch.equal(x[k], y[k]) for x, y in zip(a["members"], b["members"]) for k in x
    )
