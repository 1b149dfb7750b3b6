"""Every command line the documentation shows works: each ``python train.py``, ``python evaluate.py``,
``cmdp-train``, ``cmdp-evaluate``, ``cmdp-compare``, ``python -m cmdp_rl`` and ``python -m cmdp_rl.report.compare``
line in README.md, docs/**/*.md and the comments of configs/**/*.yaml, in a code block or in backticks, and each
``e.g. key=value`` a config comment gives (with its file selected: ``env=gym`` for configs/env/gym.yaml).

- A training line is composed by Hydra over configs/ and validated as ``cmdp-train`` validates it before its first
  env step (one run: ``load_config``; a population: each agent's config); nothing trains. A multirun (``-m``) is
  expanded as Hydra's basic sweeper expands it, the preset's ``hydra.sweeper.params`` included, and validated in
  jobs that between them hold every config-group choice and every swept value (:func:`_jobs`). A resume keeps
  the run's own config: its line must compose, and change only what a resume may (``RESUMABLE``).
- An evaluate or compare line is parsed as the command parses it (``cmdp_rl.cli.evaluate.parse_options``,
  ``cmdp_rl.report.compare.parse_args``); the run directory it names is not read.
- A line shown failing (``$ command`` and its output in a code block) whose error is the config's must print
  that output; an error only a run meets (a broken env, an unwritable directory) is the business of the tests
  that run it, and such a line must compose and validate.

Placeholders: a few are given a value (``SUBSTITUTED``); the lines that cannot be checked are in ``SKIPPED``
with why, and a test keeps both lists from outliving their lines."""

from __future__ import annotations

import itertools
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper  # Hydra's own expansion of a -m sweep
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf

import cmdp_rl.cli.train  # noqa: F401 - registers the resolvers configs/config.yaml's hydra node uses
from cmdp_rl.cli.evaluate import parse_options
from cmdp_rl.config.run_config import CONFIG_DIR, ConfigError, load_config
from cmdp_rl.population.spec import agent_configs, population_active
from cmdp_rl.report.compare import parse_args as compare_args
from cmdp_rl.run.resume import _resumable
from cmdp_rl.tune.search import Settings, check_space, parse_space

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "configs").rglob("*.yaml"))]

# The command names, and what each runs: train (Hydra), evaluate (key=value options), compare (argparse).
COMMANDS = {
    "python train.py": "train",
    "cmdp-train": "train",
    "python -m cmdp_rl": "train",
    "python evaluate.py": "evaluate",
    "cmdp-evaluate": "evaluate",
    "cmdp-compare": "compare",
    "python -m cmdp_rl.report.compare": "compare",
}
_NAME = "|".join(re.escape(c) for c in sorted(COMMANDS, key=len, reverse=True))
# What may stand before a command on its line: a shell prompt, environment assignments, /usr/bin/time.
COMMAND = re.compile(rf"^(?:\$\s+)?(?:[A-Z_]+=\S*\s+)*(?:/usr/bin/time\s+)?(?P<name>{_NAME})(?![\w.-])(?P<rest>.*)$")

# Placeholders given a value, each one of those the text means: a seed S, the suite study's instance I,
# algorithm A and steps T, a table's step size, a shell loop's variables. Besides these: a `<run dir>` in a value
# becomes a name (run_dir), an argument `...` (more options) is dropped and `[option]` (usage notation:
# optional) is checked as the option.
SUBSTITUTED = {
    "seed=S": "seed=0",
    "env.instance=I": "env.instance=0",
    "algo=A ": "algo=ppo_lag ",
    "total_steps=T": "total_steps=4096",
    "algo.multiplier.lr=η": "algo.multiplier.lr=0.05",
    "$p": "mujoco",
    "$s": "0",
}
# Lines that cannot be checked, by a string in the line, and why.
SKIPPED = {
    "algo=<": "names an algorithm the reader writes (algo=<name>, algo=<method>)",
    "+experiment=...": "stands for the two sweeps the comment names (penalty_sweep, constraint_sweep: checked)",
    "reference.run=runs/ppo_ref": "reads the run that the line before it trains",
}


@dataclass(frozen=True)
class Documented:
    where: str  # file:line
    command: str  # as written, continuation lines joined
    output: str | None  # the first line shown after a `$ command`: what it prints
    fragment: bool = False  # a config comment's "e.g. key=value": part of a command line, the rest not shown

    @property
    def kind(self) -> str:
        return COMMANDS[COMMAND.match(self.command).group("name")]

    @property
    def args(self) -> list[str]:
        rest = COMMAND.match(self.command).group("rest")
        for placeholder, value in SUBSTITUTED.items():
            rest = rest.replace(placeholder, value)
        rest = re.sub(r"<([^<>]+)>", lambda m: m.group(1).replace(" ", "_"), rest)
        args = [a[1:-1] if a.startswith("[") and a.endswith("]") else a for a in shlex.split(rest, comments=True)]
        return [a for a in args if a != "..."]


def _spans(text: str, first_line: int, where: str) -> list[Documented]:
    """Commands in backticks in a paragraph (a span may wrap across lines)."""
    found = []
    for m in re.finditer(r"`([^`]+)`", text):
        code = " ".join(m.group(1).split())
        if COMMAND.match(code) and COMMAND.match(code).group("rest").strip() not in ("", "..."):
            found.append(Documented(f"{where}:{first_line + text.count(chr(10), 0, m.start())}", code, None))
    return found


def _code(lines: list[tuple[int, str]], where: str) -> list[Documented]:
    """Commands at the start of code lines (``\\`` continues a line); a ``$ command`` line's output follows it."""
    found, i = [], 0
    while i < len(lines):
        number, line = lines[i]
        while line.rstrip().endswith("\\") and i + 1 < len(lines):
            i += 1
            line = line.rstrip()[:-1] + " " + lines[i][1].strip()
        i += 1
        m = COMMAND.match(line.strip())
        rest = m.group("rest").strip() if m else ""
        if rest in ("", "...") or rest.startswith("#"):
            continue  # no command, or its name alone (`python evaluate.py ...`): what it is, not a command line
        output = None
        if line.strip().startswith("$") and i < len(lines) and not lines[i][1].strip().startswith("$"):
            output = lines[i][1].strip() or None
        found.append(Documented(f"{where}:{number}", " ".join(line.split()), output))
    return found


def _markdown(path: Path) -> list[Documented]:
    where = path.relative_to(ROOT).as_posix()
    found, fence, block, prose = [], None, [], []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        stripped = line.strip()
        if fence is None and stripped.startswith(("```", "~~~")):
            fence, block = stripped[:3], []
        elif fence is not None and stripped.startswith(fence):
            found += _code(block, where)
            fence = None
        elif fence is not None:
            block.append((number, line))
        else:
            prose.append((number, line))
    # Outside code fences: indented code lines start with the command; prose has it in backticks.
    found += _code([(n, line) for n, line in prose if "`" not in line], where)
    paragraph: list[tuple[int, str]] = []
    for number, line in [*prose, (0, "")]:
        if line.strip():
            paragraph.append((number, line))
        elif paragraph:
            found += _spans("\n".join(t for _, t in paragraph), paragraph[0][0], where)
            paragraph = []
    return found


OVERRIDE = re.compile(r"^[+~]?[\w./]+=")


def _unpunctuated(word: str) -> str:
    """``seed=0.`` at a sentence's end, ``[hazard_b].)`` closing a parenthesis: the override without them."""
    while word and word[-1] in ".,;)" and (word[-1] != ")" or word.count(")") > word.count("(")):
        word = word[:-1]
    return word


def _examples(text: str, number: int, path: Path) -> list[Documented]:
    """A config comment's ``e.g. key=value ...`` (the overrides after "e.g.", up to the first other word), as the
    command line that selects the file: ``configs/env/gym.yaml``'s with ``env=gym``."""
    words = shlex.split(text.split("e.g.", 1)[1].replace("`", " "), comments=True)
    while words and not OVERRIDE.match(words[0]):
        words.pop(0)
    examples = list(itertools.takewhile(OVERRIDE.match, words))
    if not examples:
        return []
    examples = [_unpunctuated(e) for e in examples]
    group, name = path.relative_to(ROOT / "configs").parent.as_posix(), path.stem
    select = [] if group == "." else [f"+experiment={name}" if group == "experiment" else f"{group}={name}"]
    command = "python train.py " + " ".join(shlex.quote(w) for w in [*select, *examples])
    return [Documented(f"{path.relative_to(ROOT).as_posix()}:{number}", command, None, fragment=True)]


def _yaml_comments(path: Path) -> list[Documented]:
    where = path.relative_to(ROOT).as_posix()
    comments = [(n, line.split("#", 1)[1]) for n, line in enumerate(path.read_text().splitlines(), 1) if "#" in line]
    found = _code([(n, c) for n, c in comments if "`" not in c], where)
    for n, c in comments:
        found += _spans(c, n, where)
        if "e.g." in c and not COMMAND.search(c.split("e.g.", 1)[1].replace("`", " ").strip()):
            found += _examples(c, n, path)
    return found


def documented() -> list[Documented]:
    found = []
    for path in SOURCES:
        found += _markdown(path) if path.suffix == ".md" else _yaml_comments(path)
    return sorted(set(found), key=lambda d: (d.where.split(":")[0], int(d.where.split(":")[1])))


LINES = documented()


def _skip_reason(d: Documented) -> str | None:
    return next((why for text, why in SKIPPED.items() if text in d.command), None)


@pytest.fixture(scope="module")
def hydra_compose():
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        yield compose


_VALID: set[tuple[str, ...]] = set()  # jobs validated so far


def _validate(raw) -> None:
    """What ``cmdp-train`` checks before its first env step (cmdp_rl/cli/train.py)."""
    raw = OmegaConf.to_container(raw, resolve=True)
    if population_active(raw.get("population")):
        agent_configs(raw)
    else:
        load_config(raw)


def _jobs(sweeper, overrides: list[str]) -> list[list[str]]:
    """Jobs of a basic-sweeper multirun that between them hold every job's config groups and every swept value.

    The sweep is read as Hydra's basic sweeper reads it: the preset's ``hydra.sweeper.params`` (``sweeper``: the
    composed ``hydra.sweeper``), then the command line's overrides (a later value of a key replaces an earlier
    one), each key's values as the sweeper lists them. Its jobs are the product of those lists; a sweep of a
    hundred jobs would take a minute to compose, so the jobs kept are the product over the keys that pick a config
    group (``algo=ppo,cpo``: each its own config, its own keys) with the other keys' values dealt out in turn, so
    that each value is in some job and each group choice meets a value of every key (a key one algorithm lacks
    fails in every such job)."""
    parser = OverridesParser.create()
    params = OmegaConf.to_container(sweeper.params) if sweeper.params else {}
    values: dict[str, list[str]] = {}
    for override in parser.parse_overrides([f"{k}={v}" for k, v in params.items()] + overrides):
        if not override.is_hydra_override():  # the launcher's and directories' options: composed already
            values[override.get_key_element()] = [job[0] for job in BasicSweeper.split_arguments([override], None)[0]]
    groups = [k for k in values if (CONFIG_DIR / k.lstrip("+~")).is_dir()]
    chosen = list(itertools.product(*(values[k] for k in groups)))
    count = max([len(chosen)] + [len(v) for k, v in values.items() if k not in groups])
    return [
        [chosen[i % len(chosen)][groups.index(k)] if k in groups else v[i % len(v)] for k, v in values.items()]
        for i in range(count)
    ]


def _check_search(hydra_compose, sweeper, overrides: list[str]) -> None:
    """A hyperparameter search (hydra/sweeper=cmdp_optuna, docs/tuning.md) checked as its sweeper checks it before
    its first trial (cmdp_rl/tune/search.py): the settings, the space, and a job composed and validated at
    each end of the space (``check_space``)."""
    options = OmegaConf.to_container(sweeper, resolve=True)
    settings = Settings.of(options)
    task = [o.input_line for o in OverridesParser.create().parse_overrides(overrides) if not o.is_hydra_override()]
    space, fixed = parse_space([f"{k}={v}" for k, v in (options.get("params") or {}).items()] + task)
    check_space(
        space,
        fixed,
        settings.seeds,
        lambda job: OmegaConf.to_container(hydra_compose("config", overrides=job), resolve=True),
    )


def _check_train(d: Documented, hydra_compose) -> None:
    args = d.args
    multirun = bool({"-m", "--multirun"} & set(args))
    overrides = [a for a in args if a not in ("-m", "--multirun")]
    assert all(not a.startswith("-") for a in overrides), f"{d.where}: an option cmdp-train does not take: {args}"
    parsed = OverridesParser.create().parse_overrides(overrides)
    if any(o.get_key_element() == "resume" for o in parsed):  # the run's own config: change only what a resume may
        hydra_compose("config", overrides=overrides)
        refused = [k for o in parsed if not _resumable(k := o.get_key_element().lstrip("+~")) and "hydra" not in k]
        assert not refused, f"{d.where}: a resume cannot change {refused}"
        return
    jobs = [overrides]
    if multirun:  # the sweep's own config (its sweeper, the preset's params) from the overrides that are no sweep
        fixed = [o.input_line for o in parsed if not o.is_sweep_override()]
        sweeper = hydra_compose("config", overrides=fixed, return_hydra_config=True).hydra.sweeper
        if sweeper._target_.endswith("ConstrainedOptunaSweeper"):
            return _check_search(hydra_compose, sweeper, overrides)
        assert sweeper._target_.endswith("BasicSweeper"), f"{d.where}: no check for the sweeper {sweeper._target_}"
        jobs = _jobs(sweeper, overrides)
    for job in jobs:
        if tuple(job) not in _VALID:  # several pages show the same sweep
            _validate(hydra_compose("config", overrides=job))
            _VALID.add(tuple(job))


# Optional extras the test set-up leaves out (pyproject.toml: MuJoCo Warp is 409 MB installed, its tests skip
# without it): a documented line that needs one is checked only where it is installed.
EXTRAS_NOT_IN_MAKE_TEST = ("'.[mjwarp]'",)


@pytest.mark.parametrize(
    "line",
    [pytest.param(d, marks=pytest.mark.skip(reason=_skip_reason(d))) if _skip_reason(d) else d for d in LINES],
    ids=[d.where for d in LINES],
)
def test_a_documented_command_line_works(line, hydra_compose, monkeypatch):
    if "device=cuda" in line.args:  # a GPU's command line: checked as on a machine that has one
        monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    try:
        if line.kind == "train":
            _check_train(line, hydra_compose)
        elif line.kind == "evaluate":
            if line.args != ["--help"]:
                parse_options(line.args)
        else:
            try:
                compare_args(line.args)
            except SystemExit as exc:  # argparse's refusal: its usage line is on stderr
                pytest.fail(f"{line.where}: cmdp-compare refuses {line.args} (exit {exc.code})")
    except ConfigError as exc:
        if any(extra in str(exc) for extra in EXTRAS_NOT_IN_MAKE_TEST):
            pytest.skip(f"{line.where} needs an extra `make test` does not install: {exc}")
        field = str(exc).split()[0]
        if line.fragment and not any(a.lstrip("+~").startswith(field) for a in line.args):
            return  # an option the example leaves to the rest of its command line (env=gym's env.id)
        # A line shown failing: its output is the config error's one line.
        assert line.output == f"config error: {exc}", f"{line.where}: {line.command}\n{exc}"


def test_the_documentation_is_searched():
    """The collection finds what it is for: every command, every source kind, the shown error."""
    kinds = {d.kind for d in LINES}
    files = {d.where.split(":")[0].split("/")[0] for d in LINES}
    assert kinds == {"train", "evaluate", "compare"}
    assert {"README.md", "docs", "configs"} <= files
    assert len(LINES) > 100, len(LINES)
    shown = [d for d in LINES if d.output == "config error: algo.gamma must be in [0, 1), got 1.0"]
    assert len(shown) >= 2  # README and the training guide


def test_every_skip_and_substitution_is_still_needed():
    for text in SKIPPED:
        assert any(text in d.command for d in LINES), f"SKIPPED[{text!r}] matches no documented line: drop it"
    for text in SUBSTITUTED:
        assert any(text in d.command for d in LINES), f"SUBSTITUTED[{text!r}] matches no documented line: drop it"
