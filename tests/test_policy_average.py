"""deploy.policy=average: the averaged parameters by hand, the window, and the deployed policy used
alike by the run's evaluation, its checkpoint, eval.json and evaluate.py."""

import io
import json

import pytest
import torch
from helpers.runs import eval_result, tiny
from torch import nn

from cmdp_rl import load_config, train
from cmdp_rl.cli import evaluate as evaluate_cli  # noqa: E402  (the command's main, in-process)
from cmdp_rl.deploy.average import ParameterAverage, first_averaged_iteration
from cmdp_rl.run.checkpoint import load_checkpoint
from cmdp_rl.run.rundir import load_trained


def test_running_mean_of_parameters_by_hand_and_plain_state():
    m = nn.Linear(1, 1, bias=False)
    avg = ParameterAverage()
    for w in (1.0, 2.0, 6.0):
        m.weight.data.fill_(w)
        avg.update(m)
    m.weight.data.fill_(-5.0)
    avg.apply(m)
    assert m.weight.item() == pytest.approx(3.0) and avg.count == 3  # (1 + 2 + 6) / 3
    buf = io.BytesIO()
    torch.save(avg.state_dict(), buf)
    buf.seek(0)
    again = ParameterAverage()
    again.load_state_dict(torch.load(buf, weights_only=True))  # plain tensors and numbers
    assert again.count == 3 and again.mean["weight"].item() == pytest.approx(3.0)


def test_the_window_is_the_last_fraction_of_iterations():
    assert first_averaged_iteration(100, 0.25) == 76  # iterations 76..100: 25 of them
    assert first_averaged_iteration(4, 0.5) == 3
    assert first_averaged_iteration(10, 0.01) == 10  # at least the last iterate
    assert first_averaged_iteration(10, 1.0) == 1


def test_average_is_what_the_run_evaluates_and_evaluate_py_loads(tmp_path):
    out = tmp_path / "run"
    cfg = tiny(total_steps=256, deploy={"policy": "average", "window": 0.5})
    result = train(load_config(cfg), out, echo=lambda s: None)
    assert result["final_policy"] == "average" and result["averaged_iterations"] >= 2
    state = load_checkpoint(out / "checkpoint.pt")
    avg = state["policy_average"]
    assert avg["count"] == result["averaged_iterations"]
    trained = load_trained(out)
    for name, p in trained.agent.actor.named_parameters():
        assert torch.equal(p, avg["mean"][name])  # the deployed actor is the average ...
    last = state["algo_state"]["networks"]
    assert any(not torch.equal(avg["mean"][n], last[f"actor.{n}"]) for n in avg["mean"])  # ... not the last
    trained.env.close()
    e = tmp_path / "e.json"
    assert evaluate_cli.main([f"run={out}", f"output={e}"]) == 0
    got = json.loads(e.read_text())
    assert got["final_policy"] == "average"
    keys = [f"episode_{m}" for m in ("return", "cost", "length")]
    assert {k: got[k] for k in keys} == {k: eval_result(out)[k] for k in keys}  # the same policy, same episodes


def test_bad_deploy_option_is_one_line():
    from cmdp_rl.config.run_config import ConfigError

    with pytest.raises(ConfigError, match=r"^deploy\.policy must be one of \('auto', 'last', 'average', 'mixture'\)"):
        load_config(tiny(deploy={"policy": "median"}))
    with pytest.raises(ConfigError, match=r"^deploy\.window must be in \(0, 1\], got 0\.0$"):
        load_config(tiny(deploy={"window": 0.0}))
    with pytest.raises(ConfigError, match=r"^deploy: unknown option\(s\) \['average_last'\]"):
        load_config(tiny(deploy={"average_last": 0.5}))
