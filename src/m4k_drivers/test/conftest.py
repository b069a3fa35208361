"""Shared m4k fixtures: ROS isolation, private runtime dir, process cleanup, leak check."""

from fakeclock import FakeClock
import pytest

from m4k_testing import *  # noqa: F401,F403


@pytest.fixture
def sim_robot(m4k_runtime_dir):
    """Run the simulated robot in-process (sim-bus server threads) on the test's runtime dir.

    Driver-side ``sim`` backends, in this process or in a driver_host subprocess, reach it
    through the sim-bus socket exactly as they reach the ``sim_robot`` process.
    """
    import threading

    from m4k_drivers import config as dconfig
    from m4k_drivers.sim_robot import SimRobot
    from m4k_rt.channel import ensure_runtime_dir
    rd = ensure_runtime_dir(m4k_runtime_dir)
    robot = SimRobot(dconfig.load(), rd, report_path=f'{rd}/world.json').start()
    stop = threading.Event()
    loop = threading.Thread(target=robot.run, args=(stop,), name='sim-robot-report')
    loop.start()
    try:
        yield robot
    finally:
        stop.set()
        loop.join(5)
        robot.close()


@pytest.fixture
def fake_clock():
    """Return a fresh :class:`fakeclock.FakeClock` at t = 0 (the one fake clock of these tests)."""
    return FakeClock()
