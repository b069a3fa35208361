"""The bridge's e-stop helpers (pure parts): the stamp gate and the latch state from flags."""

from m4k_rt import protocol as p
from m4k_rt.bridge.safety import CommandStampGate, latch_state


def test_stamped_command_from_before_the_release_is_dropped():
    gate = CommandStampGate()
    assert gate.accept(100) and gate.accept(200)
    gate.released()
    assert not gate.accept(200)          # the last one before the release, re-sent
    assert not gate.accept(150)
    assert gate.accept(201)              # anything newer than every earlier stamp
    assert gate.accept(0)                # unstamped: nothing to judge by
    assert gate.rejected == 2


def test_release_without_earlier_commands_lets_everything_stamped_through():
    gate = CommandStampGate()
    gate.released()
    assert gate.accept(1)


def test_latch_state_reads_the_odometry_flags():
    assert latch_state(None) == (False, False)
    assert latch_state(p.ODOM_E_STOP | p.ODOM_BRAKING) == (True, False)
    assert latch_state(p.ODOM_HOLD) == (False, True)
