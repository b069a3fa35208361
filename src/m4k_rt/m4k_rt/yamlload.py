"""Load configuration YAML refusing duplicate keys (PyYAML's safe loader keeps the last one).

YAML 1.2 requires the keys of a mapping to be unique, but PyYAML loads ``stop_distance: 0.5``
followed further down by ``stop_distance: 0.1`` as 0.1 without a word: a value edited in one
place and silently overridden in another. Every configuration file m4k reads goes through
:func:`load`, which raises :class:`DuplicateKeyError` naming the key and both lines. Merge
keys (``<<: *base``) still override as YAML means them to.

Two more ways a file used to escape as a traceback (exit 1) rather than a configuration error:
bytes that are not UTF-8 (a text stream's decoder raises UnicodeDecodeError inside PyYAML's
reader) and nesting deep enough for PyYAML's recursive composer to hit Python's recursion
limit. Both are :class:`yaml.YAMLError` subclasses here (:class:`EncodingError`,
:class:`NestingError`), so every caller that maps a YAML error to exit 2 maps these too.
Nesting is bounded at :data:`MAX_DEPTH` levels, far beyond any configuration m4k reads.
"""

from __future__ import annotations

from typing import Any, IO

import yaml
from yaml.constructor import ConstructorError
from yaml.nodes import MappingNode, Node

__all__ = ['DuplicateKeyError', 'EncodingError', 'MAX_DEPTH', 'NestingError',
           'UniqueKeyLoader', 'load']

_MERGE = 'tag:yaml.org,2002:merge'
MAX_DEPTH = 64


class EncodingError(yaml.YAMLError):
    """The file is not UTF-8 text (the position and byte are named)."""


class NestingError(yaml.YAMLError):
    """Mappings and sequences nested deeper than :data:`MAX_DEPTH` (or than Python allows)."""


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

    _depth = 0

    def compose_node(self, parent: Node | None, index: Any) -> Node | None:
        """Compose as SafeLoader does, refusing nesting past :data:`MAX_DEPTH` levels."""
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise NestingError('nested deeper than {} levels at line {}, column {}'.format(
                    MAX_DEPTH, mark.line + 1, mark.column + 1))
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

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
    """Return the document in ``stream`` (safe types only).

    DuplicateKeyError on a repeated key, EncodingError on bytes that are not UTF-8,
    NestingError past MAX_DEPTH: all yaml.YAMLError, like PyYAML's own syntax errors.
    """
    try:
        return yaml.load(stream, Loader=UniqueKeyLoader)  # noqa: S506 -- a SafeLoader subclass
    except UnicodeDecodeError as exc:
        raise EncodingError('not UTF-8 text: byte 0x{:02x} ({})'.format(
            exc.object[exc.start], exc.reason)) from None
    except RecursionError:
        raise NestingError('nested too deeply for the parser (more than {} levels)'.format(
            MAX_DEPTH)) from None
