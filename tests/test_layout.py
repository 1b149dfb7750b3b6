"""The layout keeps what the issue that shaped it asked for: experiments/ holds command lines, not logic (their
code lives in the package, where tests import it), and no test reaches into a script by its path."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Reruns itself inside a virtual environment pinned to Safety-Gymnasium's own versions, where cmdp_rl is not
# installed: its code cannot live in the package.
WHOLE_SCRIPTS = {"experiments/fidelity/safety_gym_fidelity.py"}


def test_experiment_scripts_are_thin_command_lines():
    scripts = sorted(p for p in (ROOT / "experiments").rglob("*.py") if "__pycache__" not in p.parts)
    assert len(scripts) > 20
    for path in scripts:
        name = path.relative_to(ROOT).as_posix()
        if name in WHOLE_SCRIPTS:
            continue
        tree = ast.parse(path.read_text())
        defined = [n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.ClassDef))]
        assert not defined, f"{name} defines {defined}: move them into cmdp_rl/bench or cmdp_rl/analysis"
        sources = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        assert any(m and m.startswith("cmdp_rl.") for m in sources), f"{name} runs no package module"


def test_no_test_loads_a_script_by_path():
    offenders = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        text = path.read_text()
        if path.name != "test_layout.py" and re.search(
            r"spec_from_file_location|sys\.path\.insert\(.*experiments", text
        ):
            offenders.append(path.name)
    assert not offenders, f"import the package module instead of the script: {offenders}"
