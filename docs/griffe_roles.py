"""A griffe extension for the docs site (mkdocs.yml): reST habits of hydroarm's docstrings in Markdown.

The docstrings cross-reference with Sphinx roles (``:func:`~hydroarm.model.task.references.task_for_arm```,
``:class:`ControllerPolicy```) and introduce code blocks with ``Example::``. mkdocstrings renders
Markdown, so before rendering each role becomes an optional autorefs link (a link where the
target is on the site, plain code where it is not: no warning either way; ``~`` keeps only the
last name as the text) and a paragraph's closing ``::`` becomes ``:``.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|data|attr|exc|obj|const|type):`(?P<target>[^`]+)`")
LITERAL_BLOCK = re.compile(r"::[ \t]*\n(?=[ \t]*\n)")


def _resolve(obj: griffe.Object, target: str) -> str | None:
    """The full path ``target`` names from ``obj``'s scope, or None."""
    if target.startswith("hydroarm"):
        return target
    scope: griffe.Object | None = obj
    while scope is not None:
        try:
            return scope.resolve(target)
        except (griffe.NameResolutionError, AttributeError):
            pass
        head, _, rest = target.partition(".")
        if head in scope.members:
            return f"{scope.members[head].path}.{rest}" if rest else scope.members[head].path
        scope = scope.parent
    return None


def convert(text: str, obj: griffe.Object) -> str:
    """``text`` with its Sphinx roles as optional autorefs and its ``::`` block markers as ``:``."""

    def replace(match: re.Match) -> str:
        target = match["target"].strip()
        short = target.startswith("~")
        target = target.lstrip("~!")
        title = target.rsplit(".", 1)[-1] if short else target
        path = _resolve(obj, target)
        if path is None:
            return f"`{title}`"
        return f'<autoref identifier="{path}" optional><code>{title}</code></autoref>'

    text = ROLE.sub(replace, text)
    return LITERAL_BLOCK.sub(":\n", text)


class SphinxRoles(griffe.Extension):
    """Rewrite every docstring of the loaded package once its object tree is complete."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        self._walk(pkg, set())

    def _walk(self, obj: griffe.Object, seen: set[str]) -> None:
        if obj.path in seen:
            return
        seen.add(obj.path)
        if obj.docstring is not None:
            obj.docstring.value = convert(obj.docstring.value, obj)
        for member in obj.members.values():
            if not member.is_alias:
                self._walk(member, seen)
