"""The RT classes satisfy the Protocols task bodies are typed against (m4k_rt.tasks.interfaces)."""

from m4k_rt import channel
from m4k_rt.task import RtTask
from m4k_rt.tasks.interfaces import CycleContext, RtPort


def test_an_rt_xddp_socket_is_an_rt_port(m4k_runtime_dir):
    sock = channel.RtXddpSocket(3, runtime_dir=m4k_runtime_dir)
    try:
        assert isinstance(sock, RtPort)
    finally:
        sock.close()


def test_an_rt_task_is_a_cycle_context():
    task = RtTask('t', 10, 10_000_000, lambda ctx: None, block_signals=False)
    assert isinstance(task, CycleContext)
    assert isinstance(task.t_start, int) and isinstance(task.cycles, int)


def test_an_object_missing_a_method_is_not_an_rt_port():
    class NoCount:
        def send(self, data):
            return True

        def recv_into(self, buf):
            return 0

    assert not isinstance(NoCount(), RtPort)
