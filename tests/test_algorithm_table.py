"""The algorithm table's report (lab.bench.algorithm_table, behind experiments/benchmarks/algorithm_table.py)
on hand-made run directories (seconds): the LP gap and
each constraint's violation per algorithm, mean ± sample std over seeds."""

import csv
import json
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _script():
    from lab.bench import algorithm_table

    return algorithm_table


def _run(path: Path, algo: str, seed: int, costs: list[str], limit, ret: float, cost_values: list[float]) -> None:
    from cmdp_rl.envs.grid.env import DEFAULT_LAYOUT

    path.mkdir(parents=True)
    config = {
        "algo": {"name": algo, "cost_limit": limit},
        "seed": seed,
        "env": {"name": "grid", "costs": costs, "layout": list(DEFAULT_LAYOUT), "slip": 0.1, "end_prob": 0.05},
    }
    (path / "config.yaml").write_text(yaml.safe_dump(config))
    k = len(costs)
    result = {"episode_return": ret, "steps": 4096, "train_time_s": 60.0}
    result.update({(f"episode_cost/{c}" if k > 1 else "episode_cost"): v for c, v in zip(costs, cost_values)})
    (path / "eval.json").write_text(json.dumps(result))
    name = (lambda c: f"episode_cost/{c}") if k > 1 else (lambda c: "episode_cost")
    with open(path / "metrics.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["iteration", "step", "episode_return", *(name(c) for c in costs)])
        for i in (1, 2):
            writer.writerow([i, 2048 * i, ret * i / 2, *cost_values])


def test_grid_report_gives_the_lp_gap_and_each_violation(tmp_path):
    both = ["hazard_a", "hazard_b"]
    _run(tmp_path / "grid" / "ppo_lag_s0", "ppo_lag", 0, both, [0.3, 0.15], 0.5, [0.2, 0.25])
    _run(tmp_path / "grid" / "ppo_lag_s1", "ppo_lag", 1, both, [0.3, 0.15], 0.6, [0.4, 0.05])
    _run(tmp_path / "grid_k1" / "cpo_s0", "cpo", 0, ["hazard_b"], 0.15, 0.7, [0.1])
    _script().main([str(tmp_path), "--task", "grid", "--out", str(tmp_path / "out")])
    text = (tmp_path / "out" / "algorithms.md").read_text()
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| ")}
    # LP optima: 0.626 with both budgets (K = 2), 0.692 with hazard_b <= 0.15 alone (K = 1).
    # ppo_lag: gaps 0.126 and 0.026 (mean 0.076, sample std 0.071); violations a: 0, 0.1; b: 0.1, 0.
    assert (
        "| ppo_lag | K = 2 | 4,096 | 0.550 ± 0.071 | 0.626 | 0.076 ± 0.071 | 0.300 ± 0.141 (0.3) | 0.150 ± 0.141 (0.15) | "
        "0.050 ± 0.071 | 0.050 ± 0.071 |" in rows["ppo_lag"]
    )
    assert "| cpo | K = 1 | 4,096 | 0.700 | 0.692 | -0.008 | not reported | 0.100 (0.15) |  | 0.000 |" in rows["cpo"]
    assert "not run" in rows["saute"]  # every algorithm has a row
    assert (tmp_path / "out" / "figures" / "algorithms_grid.png").stat().st_size > 0


def test_reporting_one_task_replaces_only_its_section(tmp_path):
    """--task grid into an existing page: the grid section is new, the others and the header stay."""
    both = ["hazard_a", "hazard_b"]
    _run(tmp_path / "grid" / "ppo_lag_s0", "ppo_lag", 0, both, [0.3, 0.15], 0.5, [0.2, 0.25])
    script = _script()
    out = tmp_path / "out"
    out.mkdir()
    old = (
        f"# page\n\nkept header\n\n## {script.TITLES['grid']}\n\nold grid table\n\n"
        f"## {script.TITLES['reach1d']}\n\nkept reach1d\n\n## Reading the tables\n\nkept notes\n"
    )
    (out / "algorithms.md").write_text(old)
    script.main([str(tmp_path), "--task", "grid", "--out", str(out), "--measured", "Measured today."])
    text = (out / "algorithms.md").read_text()
    assert "old grid table" not in text and "| ppo_lag | K = 2 |" in text and "Measured today." in text
    assert text.startswith("# page\n\nkept header\n") and "kept reach1d" in text and text.endswith("kept notes\n")
    assert text.index(script.TITLES["grid"]) < text.index("| ppo_lag |") < text.index(script.TITLES["reach1d"])
