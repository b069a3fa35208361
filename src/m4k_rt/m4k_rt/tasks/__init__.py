"""Task bodies of the RT process, found by name through a small registry.

A body factory is called once at start-up, in the RT process, before the tasks start::

    factory(task: config.TaskConfig, ports: Mapping[str, RtPort], shared) -> body

and returns the per-cycle callable ``body(ctx)`` (``ctx``: a CycleContext, the RtTask). The
interfaces are typed Protocols (:mod:`m4k_rt.tasks.interfaces`), so strict mypy checks bodies.
Names resolve in this order: bodies registered with :func:`register_body` (rt_core registers
``monitor``; tests and ``--body-module`` plug-ins register their own), then a module
``m4k_rt.tasks.<name>`` exposing ``make_<name>`` (imported lazily, at start-up only).
"""

import importlib
import importlib.util
from typing import cast

from m4k_rt.tasks.interfaces import BodyFactory

__all__ = ['BodyFactory', 'BodyError', 'body_exists', 'get_factory', 'register_body',
           'registered']


_registry: dict[str, BodyFactory] = {}


class BodyError(LookupError):
    """A task body name cannot be resolved to a factory."""


def register_body(name: str, factory: BodyFactory) -> None:
    """Register ``factory`` under ``name`` (a later registration replaces an earlier one)."""
    if not isinstance(name, str) or not name:
        raise ValueError('body name must be a non-empty str, got {!r}'.format(name))
    if not callable(factory):
        raise ValueError('body factory for {!r} must be callable, got {!r}'.format(
            name, factory))
    _registry[name] = factory


def registered() -> list[str]:
    """Return the explicitly registered body names."""
    return sorted(_registry)


def _module_name(name: str) -> str:
    return '{}.{}'.format(__name__, name)


def body_exists(name: str) -> bool:
    """Tell whether ``name`` resolves (registered, or a module in this package), no import."""
    if name in _registry:
        return True
    if not name.isidentifier():
        return False
    try:
        return importlib.util.find_spec(_module_name(name)) is not None
    except (ImportError, ValueError):
        return False


def get_factory(name: str) -> BodyFactory:
    """Return the factory for ``name``, importing ``m4k_rt.tasks.<name>`` on first use."""
    f = _registry.get(name)
    if f is not None:
        return f
    if not body_exists(name):
        raise BodyError('unknown task body {!r} (registered: {}; or a module {})'.format(
            name, ', '.join(registered()) or 'none', _module_name('<name>')))
    mod = importlib.import_module(_module_name(name))
    factory = getattr(mod, 'make_' + name, None)
    if not callable(factory):
        raise BodyError('module {} has no factory make_{}()'.format(_module_name(name), name))
    return cast(BodyFactory, factory)  # a module's make_<name> is a factory by convention
