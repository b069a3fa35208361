"""spin_until_shutdown: a shutdown racing the executor ends the spin; real errors propagate."""

import pytest

from m4k_bridge.shutdown import spin_until_shutdown


class _Context:
    def __init__(self, ok):
        self._ok = ok

    def ok(self):
        return self._ok


def _raise(exc):
    def spin():
        raise exc
    return spin


def test_ctrl_c_ends_the_spin_quietly():
    spin_until_shutdown(_raise(KeyboardInterrupt()), _Context(ok=True))


def test_error_after_the_context_was_shut_down_is_a_shutdown():
    # What Jazzy raises when SIGTERM's shutdown lands while the wait set is being built.
    spin_until_shutdown(_raise(RuntimeError('failed to initialize wait set: the given context '
                                            'is not valid')), _Context(ok=False))


def test_error_while_the_context_is_valid_propagates():
    with pytest.raises(RuntimeError, match='real failure'):
        spin_until_shutdown(_raise(RuntimeError('real failure')), _Context(ok=True))


def test_external_shutdown_ends_the_spin_quietly():
    from rclpy.executors import ExternalShutdownException
    spin_until_shutdown(_raise(ExternalShutdownException()), _Context(ok=False))
