"""The simulated LED strip as sysfs files: the kernel's rules, and the real backends on them."""

import os

import pytest

from m4k_drivers.handler import State, Status
from m4k_drivers.led import protocol as p
from m4k_drivers.led.handler import LedHandler
from m4k_drivers.led.real import LedClassOutput, PwmOutput
from m4k_drivers.led.simfs import SysfsLeds


@pytest.fixture
def leds(tmp_path):
    made = []

    def make(**section):
        sim = SysfsLeds(str(tmp_path / 'sys'), section).start(period_s=0.005)
        made.append(sim)
        return sim
    yield make
    for sim in made:
        sim.close()


def _write(path, text):
    with open(path, 'w', encoding='ascii') as fh:
        fh.write(text + '\n')


def test_multi_intensity_follows_multi_index_and_brightness_scales(leds):
    sim = leds(multi_index=['green', 'blue', 'red'])
    with open(os.path.join(sim.led_dir, 'multi_index'), encoding='ascii') as fh:
        assert fh.read().split() == ['green', 'blue', 'red']
    _write(os.path.join(sim.led_dir, 'multi_intensity'), '255 0 51')   # green, blue, red
    _write(os.path.join(sim.led_dir, 'brightness'), '255')
    assert sim.poll() == pytest.approx((51 / 255, 1.0, 0.0))
    _write(os.path.join(sim.led_dir, 'brightness'), '0')
    assert sim.poll() == (0.0, 0.0, 0.0)


def test_what_the_kernel_rejects_is_counted_and_not_shown(leds):
    sim = leds()
    _write(os.path.join(sim.led_dir, 'multi_intensity'), '255 0')      # two values for three
    _write(os.path.join(sim.led_dir, 'brightness'), '255')
    assert sim.poll() == (0.0, 0.0, 0.0)
    # One rejected write, one count: however many polls (the thread's and ours) read it.
    assert sim.errors == 1 and 'multi_intensity' in sim.last_error


def test_a_rejected_write_counts_once_and_a_new_write_of_it_again(leds):
    """The kernel returns EINVAL once per write: re-reading the same files is no new write."""
    import time
    sim = leds(interface='pwm', chip=0, channels=[0, 1, 2])
    _write(os.path.join(sim.chip_dir, 'export'), '0')
    sim.poll()
    ch = os.path.join(sim.chip_dir, 'pwm0')
    _write(os.path.join(ch, 'period'), '1000')
    _write(os.path.join(ch, 'duty_cycle'), '400')
    _write(os.path.join(ch, 'enable'), '1')
    assert sim.poll() == pytest.approx((0.4, 0.0, 0.0))
    assert sim.errors == 0, sim.last_error
    _write(os.path.join(ch, 'duty_cycle'), '1500')
    for _ in range(5):
        assert sim.poll() == pytest.approx((0.4, 0.0, 0.0))    # kept the previous level
    time.sleep(0.05)                                           # the 5 ms poller reads it too
    assert sim.poll() == pytest.approx((0.4, 0.0, 0.0))
    assert sim.errors == 1 and 'duty_cycle 1500 > period 1000' in sim.last_error
    time.sleep(0.02)              # a later write carries a later stamp, even on coarse clocks
    _write(os.path.join(ch, 'duty_cycle'), '1500')             # the same bad value, again
    sim.poll()
    assert sim.errors == 2
    _write(os.path.join(ch, 'duty_cycle'), '600')
    assert sim.poll() == pytest.approx((0.6, 0.0, 0.0)) and sim.errors == 2


def test_pwm_export_duty_polarity_and_a_duty_longer_than_the_period(leds):
    sim = leds(interface='pwm', chip=0, channels=[0, 1, 2])
    _write(os.path.join(sim.chip_dir, 'export'), '1')
    sim.poll()
    ch = os.path.join(sim.chip_dir, 'pwm1')
    assert sorted(os.listdir(ch)) == ['duty_cycle', 'enable', 'period', 'polarity']
    _write(os.path.join(ch, 'period'), '1000')
    _write(os.path.join(ch, 'duty_cycle'), '250')
    assert sim.poll() == (0.0, 0.0, 0.0)                               # not enabled
    _write(os.path.join(ch, 'enable'), '1')
    assert sim.poll() == pytest.approx((0.0, 0.25, 0.0))
    _write(os.path.join(ch, 'polarity'), 'inversed')
    assert sim.poll() == pytest.approx((0.0, 0.75, 0.0))
    errors = sim.errors
    _write(os.path.join(ch, 'duty_cycle'), '2000')                     # EINVAL on a kernel
    assert sim.poll() == pytest.approx((0.0, 0.75, 0.0)) and sim.errors == errors + 1
    _write(os.path.join(sim.chip_dir, 'unexport'), '1')
    sim.poll()
    assert not os.path.exists(ch)


def test_led_class_backend_unchanged_on_the_simulated_tree(leds):
    sim = leds()
    out = LedHandler(lambda: LedClassOutput('rgb:status', os.path.dirname(sim.led_dir)))
    out.configure()
    out.activate()
    assert out.write((255, 0, 51, 255)) == Status.OK
    assert sim.poll() == pytest.approx((1.0, 0.0, 51 / 255))
    assert out.write((300, 0, 0, 255)) == Status.ERROR               # counted, not shown
    assert out.faults == 1 and sim.poll() == pytest.approx((1.0, 0.0, 51 / 255))
    out.deactivate()                                                 # off
    assert sim.poll() == (0.0, 0.0, 0.0)
    out.shutdown()
    assert out.state == State.FINALIZED


def test_pwm_backend_unchanged_on_the_simulated_tree(leds):
    sim = leds(interface='pwm', chip=0, channels=[0, 1, 2])
    out = PwmOutput(0, [0, 1, 2], 1000, root=os.path.dirname(sim.chip_dir))
    assert sim.poll() == (0.0, 0.0, 0.0)             # exported, configured, duty 0
    out.show(p.LedColor(255, 128, 0, 255))
    assert sim.poll() == pytest.approx((1.0, 128 / 255, 0.0), abs=1e-3)
    out.close()                                      # duty 0, disabled (left exported)
    assert sim.poll() == (0.0, 0.0, 0.0)
    assert sim.errors == 0, sim.last_error


def _refused(sim, path, text):
    import errno
    with pytest.raises(OSError) as info:
        sim.write_attr(path, text)
    return info.value.errno == errno.EINVAL or info.value.errno


def test_a_fresh_export_refuses_every_apply_until_a_period_is_written(leds):
    # Strict kernels (pwm_apply_state before mid-2024): a state with period 0 is EINVAL, so a
    # fresh export (period 0) refuses enable 0, enable 1, a duty cycle and a polarity alike.
    import errno
    sim = leds(interface='pwm', chip=0, channels=[0, 1, 2])
    sim.write_attr(os.path.join(sim.chip_dir, 'export'), '2\n')
    ch = os.path.join(sim.chip_dir, 'pwm2')
    assert open(os.path.join(ch, 'period')).read().strip() == '0'
    for attr, text in (('enable', '0'), ('enable', '1'), ('duty_cycle', '0'),
                       ('duty_cycle', '10'), ('polarity', 'normal'), ('period', '0')):
        assert _refused(sim, os.path.join(ch, attr), text) is True, (attr, text)
    assert _refused(sim, os.path.join(sim.chip_dir, 'export'), '2') == errno.EBUSY
    sim.write_attr(os.path.join(ch, 'period'), '1000\n')
    assert _refused(sim, os.path.join(ch, 'duty_cycle'), '1001') is True
    for attr, text in (('duty_cycle', '500'), ('enable', '1')):
        sim.write_attr(os.path.join(ch, attr), text + '\n')
    assert sim.poll() == pytest.approx((0.0, 0.0, 0.5))
    assert _refused(sim, os.path.join(ch, 'polarity'), 'inversed') == errno.EBUSY


def test_a_period_0_left_enabled_in_the_files_is_counted_as_einval(leds):
    sim = leds(interface='pwm', chip=0, channels=[0, 1, 2])
    _write(os.path.join(sim.chip_dir, 'export'), '0')
    sim.poll()
    _write(os.path.join(sim.chip_dir, 'pwm0', 'enable'), '1')
    sim.poll()
    assert sim.errors == 1 and 'period 0' in sim.last_error


def test_pwm_backend_configures_a_fresh_export_on_a_strict_kernel(leds):
    sim = leds(interface='pwm', chip=0, channels=[0, 1, 2])
    writes = []

    def write(path, text):
        writes.append((os.path.basename(path), text.strip()))
        sim.write_attr(path, text)
    out = PwmOutput(0, [0, 1, 2], 1_000_000, root=os.path.dirname(sim.chip_dir), write=write)
    assert writes[:2] == [('export', '0'), ('period', '1000000')]
    out.show(p.LedColor(255, 0, 128, 255))
    assert sim.poll() == pytest.approx((1.0, 0.0, 128 / 255), abs=1e-3)
    out.close()
    # Configured again over a previous user's long duty (10 ms period at 8 ms): still valid.
    for ch in (0, 1, 2):
        d = os.path.join(sim.chip_dir, f'pwm{ch}')
        for attr, text in (('period', '10000000'), ('duty_cycle', '8000000'), ('enable', '1')):
            sim.write_attr(os.path.join(d, attr), text)
    out = PwmOutput(0, [0, 1, 2], 1_000_000, root=os.path.dirname(sim.chip_dir), write=write)
    out.close()
    assert sim.poll() == (0.0, 0.0, 0.0) and sim.errors == 0, sim.last_error


def test_a_write_landing_between_the_read_and_the_stamp_is_not_counted_twice(tmp_path,
                                                                            monkeypatch):
    """The race a loaded machine hits: the poll reads the bad value, the writer truncates the
    file for its next write, then the poll takes the stamps -- the old write must not get the
    new write's stamps (it would be counted again once that write settles)."""
    import types

    from m4k_drivers.led import simfs
    # A poller too slow to interfere: this test does the interleaving itself.
    sim = SysfsLeds(str(tmp_path / 'sys'), {'interface': 'pwm', 'chip': 0,
                                            'channels': [0, 1, 2]}).start(period_s=3600)
    try:
        _interleave(sim, simfs, monkeypatch, types)
    finally:
        sim.close()


def _interleave(sim, simfs, monkeypatch, types):
    _write(os.path.join(sim.chip_dir, 'export'), '0')
    sim.poll()
    ch = os.path.join(sim.chip_dir, 'pwm0')
    for attr, text in (('period', '1000'), ('duty_cycle', '400'), ('enable', '1')):
        _write(os.path.join(ch, attr), text)
    sim.poll()
    _write(os.path.join(ch, 'duty_cycle'), '1500')
    sim.poll()
    assert sim.errors == 1
    duty = os.path.join(ch, 'duty_cycle')
    truncated = []

    def stat(path, *a, **k):
        if path == duty and not truncated:        # the writer's open('w') of the next write
            open(duty, 'w').close()
            truncated.append(path)
        return os.stat(path, *a, **k)
    fake_os = types.SimpleNamespace(**{n: getattr(os, n) for n in dir(os)
                                       if not n.startswith('__')})
    fake_os.stat = stat
    monkeypatch.setattr(simfs, 'os', fake_os)
    errors = sim.errors
    sim.poll()                                    # reads 1500, then the file is truncated
    monkeypatch.undo()
    assert truncated and sim.errors == errors
    _write(duty, '600')
    assert sim.poll() == pytest.approx((0.6, 0.0, 0.0)) and sim.errors == errors
