"""Load configuration YAML refusing duplicate keys (PyYAML's safe loader keeps the last one).

YAML 1.2 requires the keys of a mapping to be unique, but PyYAML loads ``stop_distance: 0.5``
followed further down by ``stop_distance: 0.1`` as 0.1 without a word: a value edited in one
place and silently overridden in another. Every configuration file m4k reads goes through
:func:`load`, which raises :class:`DuplicateKeyError` naming the key and both lines. Merge
keys (``<<: *base``) still override as YAML means them to.
"""

from __future__ import annotations

from typing import Any, IO

import yaml
from yaml.constructor import ConstructorError
from yaml.nodes import MappingNode, Node

__all__ = ['DuplicateKeyError', 'UniqueKeyLoader', 'load']

_MERGE = 'tag:yaml.org,2002:merge'


class DuplicateKeyError(ConstructorError):
    """A mapping gives the same key twice; ``key``, ``line`` and ``first_line`` (1-based)."""

    def __init__(self, key: Any, node: Node, first: Node) -> None:
        self.key = key
        self.line = node.start_mark.line + 1
        self.first_line = first.start_mark.line + 1
        self.file = getattr(node.start_mark, 'name', '<yaml>')
        super().__init__(None, None, str(self), node.start_mark)

    def __str__(self) -> str:
        return 'duplicate key {!r} at line {} (first given at line {}): one of the two ' \
               'would be silently ignored'.format(self.key, self.line, self.first_line)


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader that raises :class:`DuplicateKeyError` for a repeated key."""

    def construct_mapping(self, node: MappingNode, deep: bool = False) -> dict[Any, Any]:
        """Check the mapping's own keys for duplicates, then construct it as SafeLoader does."""
        if isinstance(node, MappingNode):
            seen: dict[Any, Node] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE:
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:       # unhashable: SafeLoader reports it below
                    continue
                if first is not None:
                    raise DuplicateKeyError(key, key_node, first)
                seen[key] = key_node
        return super().construct_mapping(node, deep=deep)


def load(stream: str | bytes | IO[str] | IO[bytes]) -> Any:
    """Return the document in ``stream`` (safe types only); DuplicateKeyError on a repeated key."""
    return yaml.load(stream, Loader=UniqueKeyLoader)  # noqa: S506 -- a SafeLoader subclass
