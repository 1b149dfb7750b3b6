"""MkDocs hook: the options page (guide/options.md) lists every YAML file of configs/, read at build time,
so the page cannot fall behind the configs it documents."""

from __future__ import annotations

from pathlib import Path

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
PAGE = "guide/options.md"
# The groups a run picks from, in the order a reader meets them; experiment/ and tuning/ are sweeps and
# per-pair presets, listed by name only.
GROUPS = ("algo", "env", "policy", "normalize", "logger", "population")
LISTED_BY_NAME = ("experiment", "tuning/algo", "tuning/policy")


def _block(path: Path) -> str:
    return f'```yaml title="configs/{path.relative_to(CONFIGS).as_posix()}"\n{path.read_text().rstrip()}\n```\n'


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ANN001 - MkDocs' hook signature
    if page.file.src_uri != PAGE:
        return markdown
    out = [markdown.rstrip(), "\n\n## Top-level options (`configs/config.yaml`)\n\n", _block(CONFIGS / "config.yaml")]
    for group in GROUPS:
        out.append(f"\n## `{group}=`\n")
        for path in sorted((CONFIGS / group).glob("*.yaml")):
            out.append(f"\n### `{group}={path.stem}`\n\n{_block(path)}")
    for group in LISTED_BY_NAME:
        names = ", ".join(f"`{p.stem}`" for p in sorted((CONFIGS / group).glob("*.yaml")))
        out.append(f"\n## `configs/{group}/`\n\n{names}\n")
    return "".join(out)
