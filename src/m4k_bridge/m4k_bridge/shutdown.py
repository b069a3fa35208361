"""End a node's spin quietly on Ctrl-C, SIGTERM or an external shutdown (rclpy, NRT only)."""

from __future__ import annotations

from typing import Callable, TypeVar

from rclpy.context import Context
from rclpy.executors import ExternalShutdownException

from m4k_rt.stopsignals import StopSignals

__all__ = ['spin_until_shutdown', 'stop_aware_start']

T = TypeVar('T')


def stop_aware_start(make: Callable[[], T], stop: StopSignals) -> T | None:
    """Build a node (or anything rclpy-backed); None when a stop signal interrupted it.

    A SIGTERM during start-up shuts the rclpy context down under the constructor, which then
    fails with whatever rclpy raises for an invalid context. That is a stop, not an error: it
    returns None so the caller takes its clean shutdown path. Any failure without a stop
    signal propagates.
    """
    try:
        return make()
    except Exception:  # noqa: BLE001 -- judged by whether a stop signal arrived
        if stop.stopping:
            return None
        raise


def spin_until_shutdown(spin: Callable[[], object], context: Context) -> None:
    """Run ``spin`` until the process is told to stop; re-raise anything else.

    rclpy's signal handler shuts the context down asynchronously. When that lands while the
    executor is building its wait set, Jazzy raises an ``RCLError`` ("the given context is not
    valid") instead of ``ExternalShutdownException`` -- a shutdown all the same, so it ends the
    spin like one. Any error while the context is still valid is a real failure and propagates.
    """
    try:
        spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # noqa: BLE001 -- RCLError is in a private module; judged by the context
        if context.ok():
            raise
