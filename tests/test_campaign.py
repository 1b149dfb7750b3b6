"""The benchmark campaign (lab/bench/campaign.py): a queue of runs that survives a kill, one record per finished
run, and a report rebuilt from the records alone (lab/bench/campaign_report.py)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from lab.bench import campaign_report
from lab.bench.campaign import CampaignError, import_run, load_campaign, pending, read_sessions, record_path

ROOT = Path(__file__).resolve().parents[1]
RUNNER = ROOT / "experiments" / "benchmarks" / "campaign.py"
# Three tiny Reach1D runs: 2 envs, 16-step rollouts, a checkpoint every iteration, so that a kill lands mid-run.
TINY = [
    "env.num_envs=2",
    "rollout_steps=16",
    "checkpoint_every=1",
    "algo.update_epochs=2",
    "algo.num_minibatches=2",
    "deploy.policy=last",
]
STEPS, MARK = 2048, 512  # 64 iterations; the curve at 512, 1024, 1536 and 2048 steps


def write_campaign(tmp_path: Path, **changes) -> Path:
    spec = {
        "name": "tiny",
        "results": str(tmp_path / "results"),
        "work": str(tmp_path / "work"),
        "eval_episodes": 4,
        "mark_every": MARK,
        "groups": [{"env": "reach1d", "algos": ["ppo_lag"], "seeds": [0, 1, 2], "steps": STEPS, "options": TINY}],
        **changes,
    }
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def start_runner(path: Path, log: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(RUNNER), str(path), "--nice", "0"],
        cwd=ROOT,
        stdout=open(log, "w"),
        stderr=subprocess.STDOUT,
    )


@pytest.fixture(scope="module")
def killed_and_finished(tmp_path_factory):
    """The tiny campaign, its runner killed (SIGKILL) once the second run has a checkpoint, then started again."""
    tmp = tmp_path_factory.mktemp("campaign")
    path = write_campaign(tmp)
    campaign = load_campaign(path)
    second = campaign.work / "tiny" / campaign.runs[1].id
    runner = start_runner(path, tmp / "first.log")
    deadline = time.monotonic() + 300
    while not (second / "checkpoint.pt").is_file():
        assert runner.poll() is None, (tmp / "first.log").read_text()
        assert time.monotonic() < deadline, "the second run never checkpointed"
        time.sleep(0.02)
    os.kill(runner.pid, signal.SIGKILL)
    runner.wait()
    killed_at = [p.name for p in campaign.results.glob("*.json")]
    runner = start_runner(path, tmp / "second.log")
    assert runner.wait(timeout=600) == 0, (tmp / "second.log").read_text()
    return campaign, killed_at


def test_a_killed_campaign_finishes_with_a_record_per_run_and_no_run_done_twice(killed_and_finished):
    campaign, killed_at = killed_and_finished
    first, second, third = campaign.runs
    assert killed_at == [record_path(campaign, first).name]  # the first had finished, the second not
    assert not pending(campaign)
    kinds = {run.id: [s["kind"] for s in read_sessions(campaign.work / "tiny" / run.id)] for run in campaign.runs}
    assert kinds == {first.id: ["start"], second.id: ["start", "resume"], third.id: ["start"]}
    for run in campaign.runs:  # every iteration once: the resume continued metrics.csv after its checkpoint
        lines = (campaign.work / "tiny" / run.id / "metrics.csv").read_text().splitlines()[1:]
        assert [int(line.split(",")[0]) for line in lines] == list(range(1, STEPS // 32 + 1))


def test_a_record_holds_what_a_report_needs_and_nothing_of_the_run_directory(killed_and_finished):
    campaign, _ = killed_and_finished
    record = json.loads(record_path(campaign, campaign.runs[1]).read_text())
    got = tuple(record[k] for k in ("toolkit", "algo", "env", "seed", "steps"))
    assert got == ("cmdp_rl", "ppo_lag", "reach1d", 1, STEPS)
    assert record["options"] == TINY
    assert len(record["commit"]) == 40 and isinstance(record["dirty"], bool)
    assert record["config"]["algo"]["name"] == "ppo_lag" and record["config"]["env"]["num_envs"] == 2
    assert [p["step"] for p in record["curve"]] == [512, 1024, 1536, 2048]
    assert all(p["episodes"] >= 1 and "episode_return" in p and "episode_cost" in p for p in record["curve"])
    evaluation = record["evaluation"]
    assert evaluation["headline"] == "mean_action" and evaluation["deployed"] == "last"
    for mode in ("sampled", "mean_action"):
        e = evaluation[mode]
        assert e["episodes"] == 4 and len(e["episode_return_ci95"]) == 2
        assert e["episode_cost_ci95"][0] <= e["episode_cost"] <= e["episode_cost_ci95"][1]
    assert record["training_episodes"]["episodes"] >= 1
    assert record["time"]["cpu_s"] > 0 and record["time"]["wall_s"] > 0
    assert [s["kind"] for s in record["time"]["sessions"]] == ["start", "resume"]
    assert record["load"]["min"] <= record["load"]["mean"] <= record["load"]["max"]
    assert record["machine"]["device"] == "cpu" and record["machine"]["cpu"]
    assert sorted(p.name for p in campaign.results.iterdir()) == sorted(f"{r.id}.json" for r in campaign.runs)


def test_the_report_rebuilds_byte_identical_from_the_same_records(killed_and_finished, tmp_path):
    campaign, _ = killed_and_finished
    page, figure = tmp_path / "page.md", tmp_path / "curves.png"
    page.write_text("# Benchmarks\n\nThe rest of the page.\n")
    campaign_report.write_report([campaign], page, figure)
    first = page.read_bytes(), figure.read_bytes()
    campaign_report.write_report([campaign], page, figure)
    assert (page.read_bytes(), figure.read_bytes()) == first
    text = page.read_text()
    assert text.startswith("# Benchmarks\n") and text.endswith("The rest of the page.\n")
    row = next(line for line in text.splitlines() if "| ppo_lag | cmdp_rl | 3 |" in line)
    assert "stale" not in row


def test_a_record_made_with_other_options_than_todays_defaults_is_marked_stale(killed_and_finished, tmp_path):
    campaign, _ = killed_and_finished
    records = campaign_report.read_records([campaign])
    records[0]["config"]["algo"]["lr"] = 1.0  # as if the default had been another
    cache: dict = {}
    assert campaign_report.stale_since(records[0], cache) == records[0]["date"]
    assert campaign_report.stale_since(records[1], cache) is None
    records[1]["config"]["algo"]["multiplier"]["floor"] = 0.01  # an option removed since, at the value it always
    assert campaign_report.stale_since(records[1], {}) is None  # had (the log dual's floor): not a change


def test_a_run_two_campaigns_list_is_reported_once(killed_and_finished):
    campaign, _ = killed_and_finished
    assert campaign_report.read_records([campaign, campaign]) == campaign_report.read_records([campaign])


@pytest.mark.parametrize(
    "change, message",
    [
        ({"groups": [{"env": "reach1d", "algos": ["ppo"], "seeds": [0], "steps": 0}]}, "steps must be a positive"),
        ({"groups": [{"env": "reach1d", "algos": ["ppo"], "seeds": [0], "steps": 9, "lr": 1}]}, "lr is not a field"),
        ({"groups": [{"peer": "safepo", "algos": ["x"], "seeds": [0], "steps": 9}]}, "peer must be omnisafe"),
        ({"groups": [{"algos": ["ppo"], "seeds": [0, 0], "steps": 9}]}, "listed twice"),
    ],
)
def test_a_bad_campaign_file_is_refused_in_one_line_naming_the_field(tmp_path, change, message):
    with pytest.raises(CampaignError, match=message):
        load_campaign(write_campaign(tmp_path, **change))


def test_a_run_made_elsewhere_is_recorded_from_its_files(killed_and_finished, tmp_path):
    campaign, _ = killed_and_finished
    made = campaign.work / "tiny" / campaign.runs[2].id
    copied = tmp_path / "from_the_device"
    copied.mkdir()
    for f in ("config.yaml", "metrics.csv", "eval.json"):  # what lab/bench/gpu_figures.py item 6 brings back
        (copied / f).write_bytes((made / f).read_bytes())
    other = load_campaign(write_campaign(tmp_path, name="elsewhere", results=str(tmp_path / "records")))
    path = import_run(other, copied, TINY, echo=lambda line: None)
    record = json.loads(path.read_text())
    original = json.loads(record_path(campaign, campaign.runs[2]).read_text())
    assert path.name == f"{campaign.runs[2].id}.json"  # the same run: same spec, same options
    assert record["curve"] == original["curve"] and record["evaluation"] == original["evaluation"]
    assert record["time"]["sessions"] == [] and record["time"]["train_time_s"] > 0


def test_the_page_opens_with_the_2m_table():
    assert campaign_report.table_order({1_000_000, 10_000_000, 2_000_000, 500_000}) == [2_000_000, 500_000, 1_000_000]
    assert campaign_report.table_order({1_000_000, 4096}) == [4096, 1_000_000]
