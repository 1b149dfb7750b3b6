"""The throughput benchmark runs end to end (a --quick smoke run; its figures are not checked)."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_quick_benchmark_writes_every_row(tmp_path):
    out = tmp_path / "bench.json"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "experiments" / "speed" / "benchmark_throughput.py"), "--quick", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads(out.read_text())
    assert [(row["backend"], row["num_envs"]) for row in r["rows"]] == [
        ("gym", 1),
        ("gym", 8),
        ("torch", 64),
        ("torch", 1024),
        ("torch", 16384),
    ]
    for row in r["rows"]:
        assert row["env_sps"] > 0 and row["rollout_sps"] > 0 and row["train_sps"] > 0
        assert row["iterations"] == 2 and row["train_mem"]["peak_rss_mb"] > 0
    assert r["plain_loop_sync8"]["rollout_sps"] > 0 and r["meta"]["torch_threads"] == 1
    assert {e["setting"] for e in r["extra"]} >= {"torch N=1024, policy=lstm", "torch N=1024, policy=transformer"}
    assert "train/roll" in proc.stdout and set(r["targets"]) >= {
        "train_sps_torch_1024",
        "collector_over_plain_loop_sync8",
    }
