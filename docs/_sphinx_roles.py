"""A griffe extension for the API pages (mkdocs.yml): the docstrings are numpydoc with Sphinx roles
(``:class:`~faceretarget.rig.Rig```, ``:func:`read_rig```); MkDocs renders Markdown, so each role becomes a
code span of the name it shows (the last part after ``~``), and ``::`` literal-block markers a colon."""

from __future__ import annotations

import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|attr|data|obj|exc|const|ref|term):`(~?)([^`]+)`")


def _show(m: re.Match) -> str:
    tilde, target = m.groups()
    target = re.sub(r"^.*<(.+)>$", r"\1", target).strip()
    return f"`{target.rsplit('.', 1)[-1] if tilde else target}`"


class SphinxRoles(griffe.Extension):
    """Sphinx roles in docstrings as Markdown code spans."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = _ROLE.sub(_show, obj.docstring.value)
