"""Progress: a tqdm bar with an ETA when print goes to a terminal, the plain lines otherwise."""

import io
import sys

from helpers.runs import metrics_rows, tiny

from cmdp_rl import load_config, train
from cmdp_rl.run.progress import Progress


class FakeTTY(io.StringIO):
    def isatty(self):
        return True


def run(tmp_path, monkeypatch, stream):
    monkeypatch.setattr(sys, "stdout", stream)
    train(load_config(tiny(total_steps=4 * 32, log_interval=1)), tmp_path)  # echo: print
    return stream.getvalue()


def test_terminal_gets_a_live_bar_with_eta(tmp_path, monkeypatch):
    out = run(tmp_path, monkeypatch, FakeTTY())
    assert "\r" in out and "100%" in out and "step/s" in out and "<00:00" in out  # tqdm's bar and ETA
    assert "return" in out and "lambda" in out  # the latest numbers beside the bar
    assert "iter    1 |" not in out  # no periodic lines under the bar
    assert "done: ppo_lag" in out  # the summary after it


def test_pipe_gets_the_plain_lines(tmp_path, monkeypatch):
    out = run(tmp_path, monkeypatch, io.StringIO())
    assert "\r" not in out and "%|" not in out
    assert "iter    1 |" in out and "iter    4 |" in out and "done: ppo_lag" in out


def test_own_echo_is_never_live():
    lines = []
    p = Progress(100, 0, lines.append, stream=FakeTTY())
    assert not p.live and p.row_echo == lines.append
    p.write("warning: x")
    assert lines == ["warning: x"]


def test_a_row_without_a_multiplier_prints_what_it_has():
    """An algorithm whose stats carry no lagrange_multiplier: the line and the bar leave lambda out
    (it was a KeyError halfway through the first iteration)."""
    from cmdp_rl.report.metrics import format_row

    base = {"iteration": 1, "step": 32, "sps": 100.0, "episode_return": 0.5}
    one = {**base, "episode_cost": 1.0}
    assert format_row(one) == "iter    1 | step        32 |      100 steps/s | return   0.500 | cost   1.00"
    assert format_row({**one, "lagrange_multiplier": 0.25}).endswith("| cost   1.00 | lambda  0.250")
    two = {**base, "episode_cost/a": 1.0, "episode_cost/b": 2.0}
    assert format_row(two).endswith("| cost 1.00/2.00")
    assert format_row({**two, "lagrange_multiplier/a": 0.1, "lagrange_multiplier/b": 0.2}).endswith(
        "| cost 1.00/2.00 | lambda 0.100/0.200"
    )
    stream = FakeTTY()
    bar = Progress(64, 0, print, stream=stream)
    bar.update(one)
    bar.close()
    assert "cost 1.00" in stream.getvalue() and "lambda" not in stream.getvalue()


def test_the_line_shows_the_last_hundred_finished_episodes():
    """Once an episode has ended the line never reads n/a: an iteration where none ended shows the window of the
    last 100 finished episodes (its mean return and cost, and how many), as SB3 and OmniSafe do."""
    import torch

    from cmdp_rl.report.metrics import RecentEpisodes, format_row

    recent = RecentEpisodes()
    nothing = {"iteration": 1, "step": 32, "sps": 100.0, "episode_return": float("nan"), "episode_cost": float("nan")}
    assert "n/a" in format_row(nothing, recent)  # no episode has ended yet
    recent.add(torch.tensor([1.0, 3.0]).tolist(), [[2.0], [4.0]])
    line = format_row(nothing, recent)
    assert "n/a" not in line and "return   2.000 | cost   3.00 | last 2 episodes" in line
    recent.add([10.0] * 150, [[0.0]] * 150)  # the window keeps the newest 100
    assert format_row(nothing, recent).endswith("return  10.000 | cost   0.00 | last 100 episodes")
    two = {**nothing, "episode_cost/a": 0.0, "episode_cost/b": 0.0}
    del two["episode_cost"]
    pair = RecentEpisodes()
    pair.add([1.0], [[0.5, 2.0]])
    assert "cost 0.50/2.00 | last 1 episodes" in format_row(two, pair)


def test_a_long_episode_task_never_shows_na_after_its_first_episode(tmp_path):
    """Episodes of up to 60 steps with 4-step rollouts per env end only every few iterations: every printed line
    after the first finished episode has numbers, where the iteration's own mean would read n/a."""
    lines = []
    cfg = load_config(tiny(env={"max_steps": 60}, total_steps=40 * 4 * 2, rollout_steps=4, log_interval=1))
    train(cfg, tmp_path, echo=lines.append)
    rows = [line for line in lines if line.startswith("iter ")]
    first = next(i for i, line in enumerate(rows) if "last " in line)
    assert 0 < first < len(rows) - 1  # some iterations before any episode ended, then the window
    assert all("n/a" not in line for line in rows[first:]), rows[first:]
    csv_rows = metrics_rows(tmp_path)  # metrics.csv keeps each iteration's own episodes
    assert any(r["episodes"] == "0" for r in csv_rows[first:])
