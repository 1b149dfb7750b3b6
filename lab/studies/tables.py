"""Report tables: "mean ± std" cells, markdown tables, and their CSV twins."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Sequence


def pm(
    mean: float | None, std: float | None = None, spec: str = ".3f", std_spec: str | None = None, missing: str = "n/a"
) -> str:
    """``"mean ± std"`` formatted with ``spec`` (the std with ``std_spec``, default ``spec``);
    ``missing`` where there is no mean (None or nan), the mean alone where there is no std."""
    if mean is None or not math.isfinite(mean):
        return missing
    text = f"{mean:{spec}}"
    if std is not None and math.isfinite(std):
        text += f" ± {std:{std_spec or spec}}"
    return text


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]], align: str | None = None) -> str:
    """A markdown table (no final newline). ``align``: one letter a column, ``l`` or ``r``
    (right-aligned, for numbers); default all ``l``."""
    align = align or "l" * len(header)
    if len(align) != len(header):
        raise ValueError(f"align has {len(align)} letters for {len(header)} columns")
    rule = "|" + "|".join("---:" if a == "r" else "---" for a in align) + "|"
    return "\n".join(["| " + " | ".join(header) + " |", rule] + ["| " + " | ".join(r) + " |" for r in rows])


def write_csv(path: str | Path, rows: list[dict[str, Any]]) -> None:
    """``rows`` (one dict each, the columns from the first) as CSV; an empty file for no rows."""
    if not rows:
        Path(path).write_text("")
        return
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def write_table(out: str | Path, text: str, rows: list[dict[str, Any]]) -> str:
    """Write a report's table as ``table.md`` (``text``) and ``table.csv`` (``rows``) into
    ``out``; returns ``text``."""
    out = Path(out)
    (out / "table.md").write_text(text)
    write_csv(out / "table.csv", rows)
    return text
