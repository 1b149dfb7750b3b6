"""The documentation site builds with ``mkdocs build --strict`` (mkdocs.yml): a broken link or anchor, a page
missing from the nav's targets or an API reference to a module that is not there fails the suite. And the
README's links into the checkout point at files that exist."""

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_site_builds_strictly(tmp_path):
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, "mkdocs build --strict:\n" + (proc.stdout + proc.stderr)[-4000:]
    site = tmp_path / "site"
    # The guide, the results and the API pages are there, the options page lists the configs it was built from.
    for page in ("guide/first_run", "guide/concepts", "guide/env_contract", "results", "api/config"):
        assert (site / page / "index.html").is_file(), page
    options = (site / "guide" / "options" / "index.html").read_text()
    for path in sorted((ROOT / "configs" / "algo").glob("*.yaml")):
        assert f"configs/algo/{path.name}" in options
    assert "compose_config" in (site / "api" / "config" / "index.html").read_text()  # rendered from its docstring


def test_readme_links_point_at_files_in_the_checkout():
    readme = (ROOT / "README.md").read_text()
    links = [t.split("#")[0] for t in re.findall(r"\]\(([^)\s]+)\)", readme) if "://" not in t]
    assert links, "the README links into docs/"
    missing = [t for t in links if t and not (ROOT / t).exists()]
    assert not missing, f"README.md links to missing files: {missing}"
