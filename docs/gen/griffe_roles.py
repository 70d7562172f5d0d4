"""A Griffe extension for the Python API pages: Sphinx roles become code spans.

The docstrings of ``planner`` cross-reference with reST roles (``:class:`PlanSpec```,
``:func:`plan```), which Markdown would print as they are. This turns each role into a code
span (``PlanSpec``), dropping a leading ``~``. Loaded by mkdocstrings (mkdocs.yml).
"""

from __future__ import annotations

import re
from typing import Any

from griffe import Extension, Object

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const):`~?([^`]+)`")


class SphinxRolesToCode(Extension):
    def on_object(self, *, obj: Object, **kwargs: Any) -> None:
        if obj.docstring is not None and ":" in obj.docstring.value:
            obj.docstring.value = ROLE.sub(r"`\1`", obj.docstring.value)
