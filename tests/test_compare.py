"""python -m cmdp_rl.report.compare: groups, hand-computable means and IQMs, verdicts on constructed cases,
the CLI's table, CSV and figure, and real (tiny) runs."""

import csv
import json

import numpy as np
import pytest
import yaml
from helpers.runs import tiny

from cmdp_rl import load_config, train
from cmdp_rl.report.compare import (
    INCONCLUSIVE,
    VIOLATES,
    WITHIN,
    compare,
    format_table,
    interval_estimates,
    main,
    verdict,
)


def fake_run(path, algo, seed, d, ret, cost, viol=None, iters=12):
    """A finished run directory as train.py leaves it (config.yaml, metrics.csv, eval.json)."""
    path.mkdir(parents=True)
    (path / "config.yaml").write_text(
        yaml.safe_dump(
            {"seed": seed, "total_steps": 1000, "algo": {"name": algo, "cost_limit": d}, "env": {"name": "reach1d"}}
        )
    )
    with open(path / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "episode_return", "episode_cost"])
        for i in range(iters):
            # the curves rise to the final numbers; one iteration with no finished episode (blank)
            w.writerow([100 * (i + 1), ret * (i + 1) / iters, "" if i == 3 else cost])
    ev = {"episodes": 20, "episode_return": ret, "episode_cost": cost, "cost_limit": d}
    if viol is not None:
        ev["violation_rate"] = viol
    (path / "eval.json").write_text(json.dumps(ev))
    return path


@pytest.fixture
def sweep(tmp_path):
    root = tmp_path / "sweep"
    # cpo: 8 seeds, one outlying return; costs well under d = 0.5
    for s, (r, c) in enumerate(zip([1, 2, 3, 4, 5, 6, 7, 100], [0.1, 0.2, 0.1, 0.2, 0.15, 0.1, 0.2, 0.15])):
        fake_run(root / f"cpo_s{s}", "cpo", s, 0.5, r, c, viol=0.05)
    for s, c in enumerate([1.0, 1.2, 1.1, 1.3, 0.9]):  # ppo: far over d = 0.5
        fake_run(root / f"ppo_s{s}", "ppo", s, 0.5, 2.0, c, viol=0.9)
    for s, c in enumerate([0.2, 0.8, 0.3, 0.7, 0.5]):  # ppo_lag: around d = 0.5
        fake_run(root / f"ppo_lag_s{s}", "ppo_lag", s, 0.5, 1.0, c, viol=0.5 if s % 2 else None)
    (root / "killed").mkdir()  # started, never finished
    (root / "killed" / "config.yaml").write_text(yaml.safe_dump({"seed": 9, "algo": {"name": "ppo"}}))
    return root


def test_verdict_follows_the_interval_against_the_budget():
    assert verdict(0.1, 0.5, 0.5) == WITHIN  # upper end at the budget: within
    assert verdict(0.51, 0.9, 0.5) == VIOLATES
    assert verdict(0.5, 0.9, 0.5) == INCONCLUSIVE  # lower end at the budget: not a violation
    assert verdict(0.2, 0.8, 0.5) == INCONCLUSIVE
    assert verdict(None, None, 0.5).startswith("no verdict")
    assert verdict(0.1, 0.2, None).startswith("no verdict")


def test_interval_estimates_mean_and_iqm_by_hand():
    s = interval_estimates(np.array([1, 2, 3, 4, 5, 6, 7, 100.0]), resamples=500)
    assert s["n"] == 8 and s["mean"] == pytest.approx(16.0)
    assert s["iqm"] == pytest.approx(4.5)  # the middle half: (3 + 4 + 5 + 6) / 4
    assert 1 <= s["mean_low"] < s["mean"] < s["mean_high"] <= 100
    assert s["iqm_low"] < 4.5 < s["iqm_high"] < s["mean_high"]  # the outlier moves the IQM less
    assert interval_estimates(np.array([1, 2, 3, 4, 5, 6, 7, 100.0]), resamples=500) == s  # seeded
    one = interval_estimates(np.array([3.0, np.nan]))  # a missing number is left out, not zero
    assert one["n"] == 1 and one["mean"] == 3.0 and one["mean_low"] is None


def test_groups_verdicts_and_skipped_runs(sweep):
    groups, unfinished = compare([sweep], by=["algo.name"], resamples=500)
    by = {g.label: g for g in groups}
    assert list(by) == ["algo.name=cpo", "algo.name=ppo", "algo.name=ppo_lag"]
    assert [len(g.runs) for g in groups] == [8, 5, 5]
    assert [u.path.name for u in unfinished] == ["killed"]
    assert by["algo.name=cpo"].verdict == WITHIN
    assert by["algo.name=ppo"].verdict == VIOLATES
    assert by["algo.name=ppo_lag"].verdict == INCONCLUSIVE
    assert by["algo.name=ppo"].stats["episode_cost"]["mean"] == pytest.approx(1.1)
    assert by["algo.name=ppo_lag"].stats["violation_rate"]["n"] == 2  # three eval.json lack it
    text = format_table(groups)
    assert "algo.name=ppo_lag" in text and WITHIN in text and "16.000 [" in text and "4.500 [" in text


def test_default_grouping_is_everything_but_the_seed(sweep):
    groups, _ = compare([sweep / "cpo_s0", sweep / "cpo_s1", sweep / "ppo_s0"], resamples=200)
    assert [(g.label, len(g.runs)) for g in groups] == [("algo.name=cpo", 2), ("algo.name=ppo", 1)]
    assert groups[1].verdict.startswith("no verdict")  # one run: no interval over runs


def test_cli_prints_the_table_and_writes_csv_and_figure(sweep, tmp_path, capsys):
    out, png = tmp_path / "t.csv", tmp_path / "curves.png"
    assert main([str(sweep), "--by", "algo.name", "--csv", str(out), "--figure", str(png), "--resamples", "300"]) == 0
    text = capsys.readouterr().out
    assert "mean [95% CI]" in text and "IQM [95% CI]" in text and "skipped" in text and "killed" in text
    rows = {r["group"]: r for r in csv.DictReader(open(out))}
    assert rows["algo.name=ppo"]["verdict"] == VIOLATES and rows["algo.name=ppo"]["runs"] == "5"
    assert float(rows["algo.name=cpo"]["episode_return_iqm"]) == pytest.approx(4.5)
    assert float(rows["algo.name=cpo"]["episode_cost_mean_high"]) <= 0.5
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_cli_refuses_what_is_not_a_run(tmp_path, capsys):
    assert main([str(tmp_path / "nowhere")]) == 2
    assert main([str(tmp_path)]) == 2
    assert "no run directory" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(tmp_path), "--resamples", "5"])


def test_real_runs_over_two_seeds(tmp_path, capsys):
    evals = []
    for seed in (0, 1):
        out = tmp_path / f"s{seed}"
        evals.append(train(load_config(tiny(seed=seed)), out, echo=lambda s: None))
    groups, unfinished = compare([tmp_path], resamples=200)
    assert not unfinished and len(groups) == 1 and len(groups[0].runs) == 2
    g = groups[0]
    assert g.cost_limit == 0.2 and g.label == "all runs"
    for name in ("episode_return", "episode_cost", "violation_rate"):
        assert g.stats[name]["mean"] == pytest.approx(np.mean([e[name] for e in evals]))
        assert g.stats[name]["mean_low"] <= g.stats[name]["mean"] <= g.stats[name]["mean_high"]
    assert main([str(tmp_path), "--figure", str(tmp_path / "c.png"), "--resamples", "200"]) == 0
    assert (tmp_path / "c.png").is_file()


def test_bootstrap_leaves_numpys_global_generator_as_it_was():
    np.random.seed(123)
    want = np.random.rand()
    np.random.seed(123)
    interval_estimates(np.arange(6.0), resamples=200, seed=4)
    assert np.random.rand() == want
    assert interval_estimates(np.arange(6.0), resamples=200, seed=5) != interval_estimates(
        np.arange(6.0), resamples=200, seed=4
    )
