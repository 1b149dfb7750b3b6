"""The layout keeps what shaped it: the library (cmdp_rl/, the wheel) holds what a user imports, one package per
concept; benchmarks, studies and fidelity checks are checkout-only lab code (lab/), never imported by the library;
experiments/ holds thin command lines over lab/; and no test reaches into a script by its path."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Reruns itself inside a virtual environment pinned to Safety-Gymnasium's own versions, where cmdp_rl is not
# installed: its code cannot live in lab/ either.
WHOLE_SCRIPTS = {"experiments/fidelity/safety_gym_fidelity.py"}
MAX_FUNCTION_LINES = 60
MAX_MODULE_LINES = 500


def test_experiment_scripts_are_thin_command_lines():
    scripts = sorted(p for p in (ROOT / "experiments").rglob("*.py") if "__pycache__" not in p.parts)
    assert len(scripts) > 20
    for path in scripts:
        name = path.relative_to(ROOT).as_posix()
        if name in WHOLE_SCRIPTS:
            continue
        tree = ast.parse(path.read_text())
        defined = [n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.ClassDef))]
        assert not defined, f"{name} defines {defined}: move them into lab/bench or lab/studies"
        sources = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        assert any(m and m.startswith("lab.") for m in sources), f"{name} runs no lab module"


def test_no_test_loads_a_script_by_path():
    offenders = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        text = path.read_text()
        if path.name != "test_layout.py" and re.search(
            r"spec_from_file_location|sys\.path\.insert\(.*experiments", text
        ):
            offenders.append(path.name)
    assert not offenders, f"import the package module instead of the script: {offenders}"


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    found = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    return found | {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}


def test_the_library_never_imports_lab_code():
    offenders = [
        p.relative_to(ROOT).as_posix()
        for p in sorted((ROOT / "cmdp_rl").rglob("*.py"))
        if any(m == "lab" or m.startswith("lab.") for m in _imports(p))
    ]
    assert not offenders, f"the library imports checkout-only lab code: {offenders}"


def test_the_package_root_holds_one_package_per_concept():
    entries = sorted(p.name for p in (ROOT / "cmdp_rl").iterdir() if p.name not in {"__pycache__", "py.typed"})
    assert len(entries) <= 13, entries
    modules = [e for e in entries if e.endswith(".py")]
    assert modules == ["__init__.py", "__main__.py"], f"modules at the root belong in a package: {modules}"


def test_tests_share_code_through_helpers_only():
    """A test module imports shared code from tests/helpers/, never from another test module or from conftest.py
    (which holds fixtures only): moving or renaming one test then breaks no other."""
    tests = ROOT / "tests"
    local = {p.stem for p in tests.glob("*.py")}
    offenders = []
    for path in sorted([*tests.glob("*.py"), *(tests / "helpers").glob("*.py")]):
        reached = {m.split(".")[0] for m in _imports(path)} & local
        if reached:
            offenders.append(f"{path.relative_to(ROOT).as_posix()} imports {sorted(reached)}")
    assert not offenders, f"move what is shared into tests/helpers/: {offenders}"
    assert (tests / "helpers" / "__init__.py").is_file()


def _functions(path: Path) -> list[tuple[str, int]]:
    """Each function of ``path`` (methods and nested ones too) and its length in lines, decorators included."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            start = min([node.lineno, *(d.lineno for d in node.decorator_list)])
            out.append((node.name, node.end_lineno - start + 1))
    return out


def test_every_function_of_the_library_fits_on_a_screen():
    """A reader sees a whole function at once (60 lines): a longer one is split where its steps are, each step named
    for what it does, rather than squeezed."""
    offenders = [
        f"{p.relative_to(ROOT).as_posix()}: {name} ({n} lines)"
        for p in sorted((ROOT / "cmdp_rl").rglob("*.py"))
        for name, n in _functions(p)
        if n > MAX_FUNCTION_LINES
    ]
    assert not offenders, f"split these by their steps: {offenders}"


def test_every_module_of_the_library_holds_one_concept():
    """A module over 500 lines holds more than one concept: split it by concept, each part named for what it owns."""
    offenders = [
        f"{p.relative_to(ROOT).as_posix()} ({n} lines)"
        for p in sorted((ROOT / "cmdp_rl").rglob("*.py"))
        if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES
    ]
    assert not offenders, f"split these by concept: {offenders}"


def _layers() -> list[str]:
    """The layer order docs/architecture.md draws (its "Layers" section's block), bottom to top."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = text.split("## Layers", 1)[1].split("```", 2)[1]
    return [line.split()[0] for line in block.strip().splitlines()]


def _layer_of(module: str) -> str:
    """``cmdp_rl.<package>...``'s layer: the package's name, ``cmdp_rl`` for the package root."""
    parts = module.split(".")
    return "cmdp_rl" if len(parts) == 1 or parts[1] in {"__init__", "__main__"} else parts[1]


def test_no_module_imports_from_a_layer_above_its_own():
    """Every import of the library, type-only ones included, goes down the layer order (or stays in its package):
    a reader can learn the library bottom-up, and a lower layer stands without the ones above it."""
    order = _layers()
    rank = {name: i for i, name in enumerate(order)}
    packages = {p.name for p in (ROOT / "cmdp_rl").iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert packages | {"cmdp_rl"} == set(order), f"every package has its place in the layers: {sorted(packages)}"
    offenders = []
    for path in sorted((ROOT / "cmdp_rl").rglob("*.py")):
        rel = path.relative_to(ROOT / "cmdp_rl").parts
        own = "cmdp_rl" if len(rel) == 1 and rel[0] == "__init__.py" else rel[0]
        if own == "__main__.py":  # python -m cmdp_rl: the command line's entry, above every layer
            continue
        for module in sorted(m for m in _imports(path) if m == "cmdp_rl" or m.startswith("cmdp_rl.")):
            if rank[_layer_of(module)] > rank[own]:
                offenders.append(f"{path.relative_to(ROOT).as_posix()} ({own}) imports {module}")
    assert not offenders, f"imports from a higher layer: {offenders}"
