"""The results writer of m4k_bench: stamped folders, provenance, JSON and Markdown tables.

Every tool that writes results (bench, soak, fuzz, the demo, the scenarios, reaction, the
flight-recorder and live-view benches) takes its pieces from here, so a results folder looks
the same whoever wrote it:

* :func:`stamped_dir` makes ``<parent>/<prefix><UTC stamp>`` (``-2``, ``-3`` ... when taken);
* :func:`write_json` writes a summary (indented, newline-terminated) with its
  :func:`m4k_bench.benchlib.provenance.provenance` -- commit, machine, UTC time -- unless the
  document already has one;
* :func:`write_text` writes a Markdown page, :func:`md_table` renders a table's lines.
"""

from __future__ import annotations

import datetime
import json
import os
from typing import Any, Mapping, Sequence

from m4k_bench.benchlib import provenance

__all__ = ['md_table', 'stamp', 'stamped_dir', 'write_json', 'write_text']


def stamp(now: datetime.datetime | None = None) -> str:
    """Return the UTC time stamp of a results folder (``20261126T130501Z``)."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    return now.strftime('%Y%m%dT%H%M%SZ')


def stamped_dir(parent: str, prefix: str = '', when: str | None = None) -> str:
    """Create and return a new folder ``<parent>/<prefix><stamp>`` (never an existing one)."""
    os.makedirs(parent, exist_ok=True)
    base = os.path.join(parent, prefix + (when or stamp()))
    out, n = base, 1
    while True:
        try:
            os.makedirs(out)
            return out
        except FileExistsError:
            n += 1
            out = '{}-{}'.format(base, n)


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    """Return a Markdown table's lines."""
    out = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    out += ['| ' + ' | '.join(str(c) for c in r) + ' |' for r in rows]
    return out


def write_json(path: str, doc: Mapping[str, Any], *, with_provenance: bool = True,
               indent: int = 2) -> dict[str, Any]:
    """Write ``doc`` as JSON (plus ``provenance`` unless present); return what was written."""
    out = dict(doc)
    if with_provenance and 'provenance' not in out:
        out['provenance'] = provenance.provenance()
    os.makedirs(os.path.dirname(path) or '.', exist_ok=True)
    with open(path, 'w', encoding='utf-8') as f:
        json.dump(out, f, indent=indent, default=str)   # a numpy scalar, an enum: as text
        f.write('\n')
    return out


def write_text(path: str, text: str) -> None:
    """Write a Markdown page (or any text), newline-terminated."""
    os.makedirs(os.path.dirname(path) or '.', exist_ok=True)
    with open(path, 'w', encoding='utf-8') as f:
        f.write(text if text.endswith('\n') else text + '\n')
