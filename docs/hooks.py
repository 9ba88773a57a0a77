"""MkDocs hook: the configuration reference is generated from the configuration classes
(``safeswitch.core.config.reference``), so it cannot drift from the code."""

from __future__ import annotations

import re
from typing import Any

MARKER = "<!-- config-reference -->"


def on_page_markdown(markdown: str, **_: Any) -> str:
    if MARKER not in markdown:
        return markdown
    from safeswitch.core.config import reference
    from safeswitch.leftturn.config import TrafficConfig
    from safeswitch.training.config import EnvTrainConfig, TrainConfig

    generated = "\n".join(
        (
            reference(TrainConfig, "A training configuration (`safeswitch train --config`)"),
            reference(TrafficConfig, "Traffic (`traffic:` in a training configuration)"),
            reference(
                EnvTrainConfig,
                "Any Gymnasium environment (`safeswitch train --config` with an `env_id`)",
            ),
        )
    )
    return markdown.replace(MARKER, generated)


ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|exc|obj):<code>(~?)([^<]*)</code>")


def on_page_content(html: str, **_: Any) -> str:
    """The docstrings' reStructuredText roles (``:func:`name```) shown as code, the ``~`` form
    by its last component, as Sphinx would."""
    return ROLE.sub(lambda m: f"<code>{m[2].split('.')[-1] if m[1] else m[2]}</code>", html)
