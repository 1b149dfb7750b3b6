"""The package as a user installs it: the wheel built from this checkout, installed into a fresh
directory, run from a directory outside the checkout (configs read from the wheel, commands from its
entry points)."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = (
    "import cmdp_rl\n"
    "from cmdp_rl.config.run_config import CONFIG_SOURCE, compose_config\n"
    "print(cmdp_rl.__file__)\n"
    "print(CONFIG_SOURCE)\n"
    "print(repr(compose_config(['env=grid', 'algo=cpo', 'seed=3'])))\n"
)

FIND_SWEEPER = (
    "import sys\n"
    "from hydra.core.plugins import Plugins\n"
    "from hydra.plugins.sweeper import Sweeper\n"
    "(found,) = [s for s in Plugins.instance().discover(Sweeper) if s.__name__ == 'ConstrainedOptunaSweeper']\n"
    "print(sys.modules[found.__module__].__file__)\n"
)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The wheel, installed without dependencies (the test's own environment has them) into a folder
    that only PYTHONPATH points at."""
    tmp = tmp_path_factory.mktemp("package")
    # Built from a copy of what the build reads, so that setuptools' build/ and egg-info stay out of the checkout
    # (a stale build/lib would otherwise leak deleted modules into later wheels).
    source = tmp / "source"
    junk = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in (
        "cmdp_rl",
        "configs",
        "lab",
        "hydra_plugins",
    ):  # lab/ too: the check below is that setup.py leaves it out
        shutil.copytree(ROOT / name, source / name, ignore=junk)
    for name in ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md"):
        shutil.copy2(ROOT / name, source / name)
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp / "dist"), "."],
        cwd=source,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = (tmp / "dist").glob("cmdp_rl-*.whl")
    site = tmp / "site"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert install.returncode == 0, install.stderr[-3000:]
    return site


def _run(site: Path, cwd: Path, *cmd: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(site), "OMP_NUM_THREADS": "1"}
    return subprocess.run(list(cmd), cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_the_wheel_ships_configs_and_composes_them_as_the_checkout_does(installed, tmp_path):
    assert (installed / "cmdp_rl" / "configs" / "config.yaml").is_file()
    # Benchmarks, studies and fidelity checks are checkout-only lab code, never in the wheel.
    assert not (installed / "lab").exists()
    assert not [p for p in installed.rglob("*.py") if p.parent.name in ("bench", "analysis", "studies", "fidelity")]
    # The search's sweeper ships beside the package, where Hydra looks for plugins, and Hydra finds the wheel's copy.
    found = _run(installed, tmp_path, sys.executable, "-c", FIND_SWEEPER)
    assert found.returncode == 0, found.stderr[-3000:]
    assert Path(found.stdout.strip()).is_relative_to(installed / "hydra_plugins" / "cmdp_tune")
    from_wheel = _run(installed, tmp_path, sys.executable, "-c", COMPOSE)
    from_checkout = subprocess.run([sys.executable, "-c", COMPOSE], cwd=ROOT, capture_output=True, text=True)
    assert from_wheel.returncode == 0 and from_checkout.returncode == 0, from_wheel.stderr + from_checkout.stderr
    wheel_module, wheel_source, wheel_cfg = from_wheel.stdout.splitlines()
    checkout_module, checkout_source, checkout_cfg = from_checkout.stdout.splitlines()
    assert Path(wheel_module).is_relative_to(installed)  # the wheel's copy, not the checkout's
    assert Path(checkout_module).is_relative_to(ROOT)
    assert wheel_source == "pkg://cmdp_rl.configs" and Path(checkout_source) == ROOT / "configs"
    assert wheel_cfg == checkout_cfg and "GridEnvConfig" in wheel_cfg


def test_installed_wheel_trains_evaluates_and_compares_outside_the_checkout(installed, tmp_path):
    """The issue's check: ``python -m cmdp_rl algo=ppo_lag env=reach1d total_steps=4096`` from a
    directory outside the checkout writes a finished run; the console scripts read it back."""
    train = _run(
        installed, tmp_path, sys.executable, "-m", "cmdp_rl", "algo=ppo_lag", "env=reach1d", "total_steps=4096"
    )
    assert train.returncode == 0, train.stderr[-3000:]
    (run,) = (tmp_path / "outputs").glob("*/*_ppo_lag_reach1d_s0")
    for name in ("config.yaml", "metrics.csv", "eval.json", "checkpoint.pt", "run_info.json"):
        assert (run / name).is_file(), name
    result = json.loads((run / "eval.json").read_text())
    assert result["episodes"] == 20 and result["cost_limit"] == 1.0
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 2  # header, 2 iterations of 2048 steps

    # The console scripts land beside the package (pip's --target puts them in bin/).
    evaluate = _run(installed, tmp_path, str(installed / "bin" / "cmdp-evaluate"), f"run={run}", "episodes=2")
    assert evaluate.returncode == 0, evaluate.stderr[-3000:]
    assert "ppo_lag on reach1d" in evaluate.stdout and "episode_return" in evaluate.stdout
    bad = _run(installed, tmp_path, str(installed / "bin" / "cmdp-train"), "algo=no_such_algo")
    assert bad.returncode != 0 and "no_such_algo" in bad.stderr
    compare = _run(installed, tmp_path, str(installed / "bin" / "cmdp-compare"), str(tmp_path / "outputs"))
    assert compare.returncode == 0, compare.stderr[-3000:]
    assert "all runs  1     return" in compare.stdout and f"{result['episode_return']:.3f}" in compare.stdout
