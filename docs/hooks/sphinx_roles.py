"""MkDocs hook: the docstrings cite code with Sphinx roles (``:func:`load_config```), which Markdown renders as
``:func:<code>load_config</code>``; the API pages show the code span alone."""

from __future__ import annotations

import re

ROLE = re.compile(r":(?:func|class|data|mod|meth|attr|obj|exc):(<code>)")


def on_page_content(html: str, page, config, files) -> str:  # noqa: ANN001 - MkDocs' hook signature
    return ROLE.sub(r"\1", html)
