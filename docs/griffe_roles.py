"""A griffe extension for the API reference: dualcal's docstrings use Sphinx's roles (``:func:`x```, as numpydoc
does), which mkdocstrings would show as they are, since it renders docstrings as Markdown: each becomes a code
span of its target (a short name for ``~``)."""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:func|meth|class|mod|data|attr|exc|obj):`(~?)([^`<>]+?)`")


class SphinxRoles(griffe.Extension):
    """``:func:`~dualcal.files.io.load_rig``` -> `load_rig`; ``:func:`dualcal.x``` -> `dualcal.x`."""

    def on_object(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = ROLE.sub(_code, obj.docstring.value)


def _code(match: re.Match) -> str:
    short, target = match.groups()
    return f"`{target.rsplit('.', 1)[-1] if short else target}`"
