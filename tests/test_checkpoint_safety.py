"""Loading someone else's run directory runs none of their code (docs/checkpoints.md).

A crafted checkpoint (a pickled object whose loading would create a file) is refused in one line
with exit status 2 by ``evaluate.py``, ``train.py resume=...`` and a population's resume, and the
file is never created; ``compare`` reads no checkpoint. A config.yaml with a Python tag is refused
the same way. Every registered algorithm's checkpoint loads with ``torch.load(weights_only=True)``
and holds no pickled bytes; the converter turns an old run into that format.
"""

import collections
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.cli import train_py
from helpers.runs import ROOT, tiny

from cmdp_rl import load_config, train
from cmdp_rl.cli import evaluate as evaluate_cli  # noqa: E402  (the command's main, in-process)
from cmdp_rl.config.registry import component, load_builtins, names
from cmdp_rl.population import population
from cmdp_rl.report.compare import main as compare_main
from cmdp_rl.report.plot import main as plot_main
from cmdp_rl.run.checkpoint import (
    FORMAT_VERSION,
    CheckpointError,
    UnsafeCheckpointError,
    decode,
    encode,
    load_checkpoint,
    save_checkpoint,
)
from cmdp_rl.run.convert import main as convert_main
from cmdp_rl.run.migrations import is_legacy


class CreatesAFile:
    """Unpickling this opens ``path`` for writing: the file appears if the pickle is ever run."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def craft(checkpoint: Path, target: Path) -> None:
    """Replace ``checkpoint`` by one that looks like a cmdp_rl checkpoint plus the payload."""
    state = torch.load(checkpoint, weights_only=True)
    state["payload"] = CreatesAFile(target)
    torch.save(state, checkpoint)


def snapshot(run: Path) -> dict[str, bytes]:
    """Every file of a run directory but Hydra's records of a command, which Hydra writes before
    train.py runs (a resume's .hydra/resume_*/ and its log, train.log), and the directory's lock
    file, which names the last process that held the directory (run/ownership.py: a resume takes
    the lock before it reads the checkpoint, so that two resumes cannot race)."""
    return {
        str(p.relative_to(run)): p.read_bytes()
        for p in run.rglob("*")
        if p.is_file() and ".hydra" not in p.parts and p.name not in ("train.log", ".run.lock")
    }


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("safety") / "run"
    train(load_config(tiny(total_steps=2 * 32)), out, echo=lambda _: None)
    return out


def _one_line_refusal(text: str, path: Path, what: str) -> None:
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    assert str(path) in lines[0] and what in lines[0], lines[0]


def test_evaluate_and_resume_refuse_a_crafted_checkpoint(run_dir, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    target = tmp_path / "created_by_the_checkpoint"
    craft(run / "checkpoint.pt", target)
    before = snapshot(run)

    assert evaluate_cli.main([f"run={run}"]) == 2
    _one_line_refusal(capsys.readouterr().err, run / "checkpoint.pt", "holds io.open, which is not data")
    assert not target.exists()

    proc = train_py(f"resume={run}", "total_steps=128")  # train.py's main(), here as evaluate's above
    assert proc.returncode == 2, proc.stderr[-2000:]
    _one_line_refusal(proc.stderr, run / "checkpoint.pt", "cannot resume: checkpoint:")
    assert "io.open" in proc.stderr and not target.exists()
    assert snapshot(run) == before  # nothing written (but Hydra's record of the command)

    with pytest.raises(UnsafeCheckpointError):  # the library call too
        load_checkpoint(run / "checkpoint.pt")
    assert not target.exists()


def test_compare_reads_no_checkpoint(run_dir, tmp_path, capsys):
    run = tmp_path / "sweep" / "run"
    shutil.copytree(run_dir, run)
    target = tmp_path / "created_by_the_checkpoint"
    craft(run / "checkpoint.pt", target)
    code = compare_main([str(tmp_path / "sweep")])  # `python -m cmdp_rl.report.compare`'s main(), in this process
    out = capsys.readouterr()
    assert code == 0, out.err[-2000:]
    assert "violation rate" in out.out and not target.exists()


def test_a_config_yaml_with_a_python_tag_is_refused(run_dir, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    target = tmp_path / "created_by_the_yaml"
    (run / "config.yaml").write_text(f"seed: !!python/object/apply:os.system ['touch {target}']\n")
    assert evaluate_cli.main([f"run={run}"]) == 2
    _one_line_refusal(capsys.readouterr().err, run / "config.yaml", "is not valid YAML")
    assert plot_main([str(run), "-o", str(tmp_path / "curves.png")]) == 2
    _one_line_refusal(capsys.readouterr().err, run / "config.yaml", "plot:")
    assert not target.exists() and not (tmp_path / "curves.png").exists()


@pytest.mark.parametrize("name", ["checkpoint.pt", "population.pt"])  # its name before it took a run's
def test_the_population_resume_refuses_a_crafted_checkpoint(tmp_path, name):
    raw = tiny(env={"backend": "torch", "num_envs": 4, "stagger": True}, total_steps=2 * 64)
    raw["population"] = {"seeds": 2}
    out = tmp_path / "pop"
    train(population(raw), out, echo=lambda _: None)
    (out / "checkpoint.pt").rename(out / name)
    target = tmp_path / "created_by_the_checkpoint"
    craft(out / name, target)
    before = snapshot(out)
    proc = train_py(f"resume={out}", "total_steps=512")
    assert proc.returncode == 2, proc.stderr[-2000:]
    _one_line_refusal(proc.stderr, out / name, "holds io.open, which is not data")
    assert not target.exists() and snapshot(out) == before


def _tiny_run_of(algo: str) -> dict:
    """A two-iteration run of ``algo`` on Reach1D (or the env its options name): off-policy algorithms (a warm-up option) update
    in the second iteration, so their optimizers and buffer hold something."""
    options = component("algo", algo).options
    fields = set(options.__dataclass_fields__)
    cfg = {"name": algo}
    if "warmup_steps" in fields:
        cfg.update(warmup_steps=32, batch_size=16)
    for key in ("update_epochs", "num_minibatches", "critic_minibatches"):
        if key in fields:
            cfg[key] = 2 if key != "update_epochs" else 1
    run = tiny(total_steps=2 * 32) | {"algo": cfg, "checkpoint_every": 1}
    if options.tiny_env:  # an algorithm for envs of its own kind (AlgoConfig.envs), e.g. a multi-agent one
        run["env"] = dict(options.tiny_env)
    return run


load_builtins()


@pytest.mark.parametrize("algo", names("algo"))
def test_every_algorithms_checkpoint_is_plain_data(algo, tmp_path):
    """Enrolled from the registry: torch's safe unpickler reads the checkpoint as it is (no
    allow-listed type), and nowhere in it are bytes (a pickle inside)."""
    train(load_config(_tiny_run_of(algo)), tmp_path, echo=lambda _: None)
    raw = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert raw["format"] == FORMAT_VERSION and raw["algo"] == algo

    def walk(value, where):
        assert not isinstance(value, (bytes, bytearray)), where
        if isinstance(value, dict):
            for k, v in value.items():
                walk(v, f"{where}.{k}")
        elif isinstance(value, (list, tuple)):
            for i, v in enumerate(value):
                walk(v, f"{where}[{i}]")

    walk(raw, "checkpoint")
    assert raw["collector"] is not None and raw["members"][0]["algo_state"]["networks"]


def test_encode_round_trips_numpy_values_and_refuses_objects(tmp_path):
    state = {
        "array": np.arange(12, dtype=np.uint32).reshape(3, 4)[:, ::2],  # not contiguous
        "zero_d": np.array(2.5, dtype=np.float32),
        "scalar": np.float64(0.1),  # also a Python float: must come back a numpy scalar
        "int": np.int64(7),
        "flag": np.bool_(True),
        "queue": collections.deque([np.float32(1.5), 2], maxlen=3),
        "ordered": collections.OrderedDict(w=torch.ones(2)),
        "python_rng": (3, (1, 2, 3), None),
    }
    save_checkpoint(tmp_path / "c.pt", state)
    back = load_checkpoint(tmp_path / "c.pt")
    assert np.array_equal(back["array"], state["array"]) and back["array"].dtype == np.uint32
    assert back["zero_d"].shape == () and back["zero_d"].dtype == np.float32
    assert type(back["scalar"]) is np.float64 and back["scalar"] == state["scalar"]
    assert type(back["int"]) is np.int64 and type(back["flag"]) is np.bool_
    assert back["queue"] == state["queue"] and back["queue"].maxlen == 3 and type(back["queue"][0]) is np.float32
    assert isinstance(back["ordered"], collections.OrderedDict) and torch.equal(back["ordered"]["w"], torch.ones(2))
    assert back["python_rng"] == state["python_rng"]
    assert decode(encode(state))["int"] == 7
    for bad, where in ((b"\x80\x04", "state.env.blob"), (object(), "state.env.blob")):
        with pytest.raises(TypeError, match=r"state\.env\.blob is a builtins\.(bytes|object)"):
            save_checkpoint(tmp_path / "bad.pt", {"env": {"blob": bad}})
    assert not (tmp_path / "bad.pt").exists() and not (tmp_path / "bad.pt.tmp").exists()


def test_a_damaged_file_is_corrupt_not_unsafe(tmp_path):
    (tmp_path / "c.pt").write_bytes(b"\x80\x04garbage")
    with pytest.raises(CheckpointError, match="corrupt or not a cmdp_rl checkpoint") as info:
        load_checkpoint(tmp_path / "c.pt")
    assert not isinstance(info.value, UnsafeCheckpointError)


def test_the_converter_turns_an_old_run_into_the_safe_format(tmp_path, capsys):
    run = tmp_path / "mlp"
    shutil.copytree(ROOT / "tests" / "fixtures" / "old_runs" / "mlp", run)
    with pytest.raises(UnsafeCheckpointError, match="python -m cmdp_rl.run.convert"):
        load_checkpoint(run / "checkpoint.pt")
    code = convert_main([str(run)])  # `python -m cmdp_rl.run.convert`'s main(), in this process
    out = capsys.readouterr()
    assert code == 0, out.err[-2000:]
    assert f"format 2 -> {FORMAT_VERSION}" in out.out
    state = load_checkpoint(run / "checkpoint.pt")  # the safe load, now
    networks = state["members"][0]["algo_state"]["networks"]
    assert state["format"] == FORMAT_VERSION and not is_legacy(networks)
    assert any(k.startswith("critics.cost.") for k in networks)
    assert state["members"][0]["algo_state"]["multiplier"]["constraints"]  # one multiplier state per constraint
    assert (run / "checkpoint.pt.format2").read_bytes() == (
        ROOT / "tests/fixtures/old_runs/mlp/checkpoint.pt"
    ).read_bytes()
    assert evaluate_cli.main([f"run={run}", "episodes=2"]) == 0
