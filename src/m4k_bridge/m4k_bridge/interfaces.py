"""The one loader of ROS interface classes by type name (``pkg/msg/Name``, ``pkg/srv/Name``).

The bag recorder, the flight recorder, the doctor, the live view and its bench check all turn
a type name from the graph (``ros2 topic list -t``, a Foxglove channel's schema name) into the
generated Python class; they do it here.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ['interface_class']


def interface_class(type_name: str, kind: str = 'msg') -> Any:
    """Return the class of ``pkg/<kind>/Name`` (or ``pkg/Name``, taken as a ``kind``).

    A malformed name is a ValueError; an unknown package or type raises what the import
    raises (ModuleNotFoundError, AttributeError).
    """
    parts = type_name.split('/')
    if len(parts) == 2:
        parts.insert(1, kind)
    if len(parts) != 3 or not all(parts):
        raise ValueError('not an interface type name (pkg/{}/Name): {!r}'.format(kind, type_name))
    pkg, kind, name = parts
    return getattr(importlib.import_module('{}.{}'.format(pkg, kind)), name)
