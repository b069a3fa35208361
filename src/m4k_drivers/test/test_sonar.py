from fakeclock import FakeClock
import pytest

from m4k_drivers.handler import DeviceNotFoundError, Status
from m4k_drivers.sonar import protocol as p
from m4k_drivers.sonar.handler import SonarHandler
from m4k_drivers.sonar.real import EdgeSonar, IioSonar, open_gpio_sonar
from m4k_drivers.sonar.sim import open_sim_sonar
from m4k_drivers.world import World, WorldConfig


def test_speed_of_sound_hand_values():
    assert p.speed_of_sound(0.0) == pytest.approx(331.3)
    assert p.speed_of_sound(20.0) == pytest.approx(331.3 * (293.15 / 273.15) ** 0.5)  # 343.2


@pytest.mark.parametrize('width, temp, rng, status', [
    (0.01, 0.0, 1.6565, p.STATUS_OK),                  # 331.3 * 0.01 / 2
    (2 / 343.2166, 20.0, 1.0, p.STATUS_OK),
    (0.0001, 20.0, 0.01716, p.STATUS_FAULT),           # 1.7 cm < 2 cm: too close, invalid
    (0.038, 20.0, 6.5211, p.STATUS_NO_ECHO),           # the long no-echo pulse: nothing in 4.5 m
    (0.0263, 20.0, 4.5132, p.STATUS_NO_ECHO),          # just beyond 4.5 m: nothing within range
])
def test_pulse_to_range(width, temp, rng, status):
    r = p.pulse_to_range(width, temp)
    assert r.range_m == pytest.approx(rng, abs=1e-3)
    assert r.status == status


def test_pulse_to_range_timeout_and_fault():
    assert p.pulse_to_range(None) == (0.0, p.STATUS_TIMEOUT)
    assert p.pulse_to_range(-1e-3).status == p.STATUS_FAULT
    assert p.pulse_to_range(float('nan')).status == p.STATUS_FAULT


def test_edges_to_width_takes_first_pair():
    edges = [p.Edge('falling', 5), p.Edge('rising', 1_000), p.Edge('falling', 6_001_000)]
    assert p.edges_to_width(edges) == pytest.approx(0.006)
    assert p.edges_to_width([p.Edge('rising', 1)]) is None


def _sim(cfg=None):
    clock = FakeClock()
    world = World(cfg or WorldConfig(obstacles=()), clock=clock, t0_ns=0)
    return world, clock, open_sim_sonar(world, noise_sd=0.0, sleep=clock.sleep)


def test_sim_sonar_ranges_front_wall_through_edges():
    world, clock, sonar = _sim()
    r = sonar.measure()
    # default room front wall at x = 4.2; sensor mounted 0.225 m ahead of base_link
    assert r.status == p.STATUS_OK
    assert r.range_m == pytest.approx(4.2 - 0.225, abs=1e-6)
    assert sonar.trigger.fired == 1 and sonar.trigger.short_triggers == 0


def test_sim_sonar_obstacle_in_cone():
    world, clock, sonar = _sim(WorldConfig())
    r = sonar.measure()
    assert r.range_m == pytest.approx(1.5 - 0.225, abs=1e-6)


def test_sim_sonar_no_echo_beyond_max_range_is_nothing_in_range_not_a_fault():
    # A hall: nothing within 4.5 m. The US-100 answers with its long no-echo pulse -- a valid
    # "nothing in range", not a fault (a fault would freeze the guard in every open space).
    world, clock, sonar = _sim(WorldConfig(walls=((6.0, -3.0, 6.0, 3.0),), obstacles=()))
    r = sonar.measure()
    assert r.status == p.STATUS_NO_ECHO
    h = SonarHandler(lambda: sonar)
    h.configure()
    h.activate()
    assert h.read().value.status == p.STATUS_NO_ECHO
    assert h.invalid == 0 and h.no_echo == 1 and h.faults == 0
    h.shutdown()


def test_sim_sonar_soft_surface_gives_no_echo_low_box_is_seen_under_the_laser():
    soft = {'obstacles': [{'polygon': [[1.0, -0.5], [1.2, -0.5], [1.2, 0.5], [1.0, 0.5]],
                           'surface': 'soft'}], 'walls': [[6.0, -3.0, 6.0, 3.0]]}
    world, clock, sonar = _sim(WorldConfig.from_dict(soft))
    assert sonar.measure().status == p.STATUS_NO_ECHO        # absorbed: nothing comes back
    low = {'obstacles': [{'polygon': [[1.0, -0.5], [1.2, -0.5], [1.2, 0.5], [1.0, 0.5]],
                          'height': 0.25}], 'walls': [[6.0, -3.0, 6.0, 3.0]]}
    world = World(WorldConfig.from_dict(low), clock=clock, t0_ns=0)
    assert world.sonar_cast((0.225, 0.0), 0.0, 0.13, 4.5, 0.2) == pytest.approx(0.775)
    assert world.sonar_cast((0.225, 0.0), 0.0, 0.13, 4.5, 0.3) == float('inf')   # beam above it


def test_pulse_shorter_than_min_range_is_a_fault():
    assert p.pulse_to_range(0.00005).status == p.STATUS_FAULT


def test_sim_sonar_short_trigger_is_ignored_and_times_out():
    world, clock, _ = _sim()
    sonar = open_sim_sonar(world, noise_sd=0.0, sleep=clock.sleep)
    sonar.trigger_s = 5e-6                                  # bypass the constructor check
    r = sonar.measure()
    assert r.status == p.STATUS_TIMEOUT
    assert sonar.trigger.short_triggers == 1 and sonar.trigger.fired == 0


def test_edge_sonar_rejects_short_trigger_setting():
    with pytest.raises(ValueError, match='>= 10 us'):
        EdgeSonar(None, None, 'x', trigger_s=5e-6)


def test_handler_counts_timeouts():
    world, clock, _ = _sim()
    sonar = open_sim_sonar(world, noise_sd=0.0, sleep=clock.sleep)
    sonar.trigger.dead = True
    h = SonarHandler(lambda: sonar)
    h.configure()
    h.activate()
    r = h.read()
    assert r.status == Status.OK and r.value.status == p.STATUS_TIMEOUT and h.timeouts == 1
    h.shutdown()
    assert sonar.echo.closed and sonar.trigger.closed


def test_iio_backend_reads_raw_times_scale(tmp_path):
    (tmp_path / 'in_distance_raw').write_text('1234\n')
    (tmp_path / 'in_distance_scale').write_text('0.001\n')
    dev = IioSonar(str(tmp_path))
    assert dev.measure() == pytest.approx((1.234, p.STATUS_OK))
    (tmp_path / 'in_distance_raw').write_text('5000\n')
    assert dev.measure().status == p.STATUS_NO_ECHO     # beyond 4.5 m: nothing in range
    (tmp_path / 'in_distance_raw').write_text('10\n')
    assert dev.measure().status == p.STATUS_FAULT       # 1 cm: shorter than any echo
    dev.close()


def test_iio_missing_device_names_path(tmp_path):
    with pytest.raises(DeviceNotFoundError, match='in_distance_scale: No such file'):
        IioSonar(str(tmp_path / 'iio:device7'))


def test_gpio_missing_chip_names_path():
    with pytest.raises(DeviceNotFoundError, match='/dev/gpiochip97 line 5'):
        open_gpio_sonar('/dev/gpiochip97', 5, 6)


@pytest.mark.hardware
def test_real_gpio_sonar_measures():
    h = SonarHandler(lambda: open_gpio_sonar('/dev/gpiochip0', 23, 24))
    h.configure()
    assert h.read().status == Status.OK
    h.shutdown()


class _Line:
    """A cdev-like line: trigger writes, echo events queued by the test's script."""

    def __init__(self):
        self.events = []
        self.writes = []

    def write(self, value):
        self.writes.append(value)
        if self.on_write is not None:
            self.on_write(value)

    on_write = None

    def poll(self, timeout=None):
        return bool(self.events)

    def read_event(self):
        return self.events.pop(0)

    def close(self):
        pass


class _Clocks:
    """Monotonic and realtime; ``step_ns`` is added to realtime once ``step_at`` reads passed."""

    def __init__(self, offset_ns=1_700_000_000_000_000_000):
        self.mono = 10_000_000_000
        self.offset = offset_ns

    def monotonic(self):
        self.mono += 1_000          # 1 us per read
        return self.mono

    def realtime(self):
        return self.mono + self.offset


def _edge_sonar(clocks, width_ns, stamp_clock, step_ns=0, line_clock='unknown'):
    trig, echo = _Line(), _Line()

    def fire(value):
        if value:                       # rising TRIG: echo rises 0.5 ms later
            return
        t0 = clocks.mono + 500_000
        base = clocks.offset if stamp_clock == 'realtime' else 0
        echo.events.append(p.Edge('rising', t0 + base))
        clocks.offset += step_ns        # NTP steps the wall clock during the pulse
        base = clocks.offset if stamp_clock == 'realtime' else 0
        echo.events.append(p.Edge('falling', t0 + width_ns + base))
        clocks.mono = t0 + width_ns + 10_000

    trig.on_write = fire
    return EdgeSonar(trig, echo, 'fake', hold=lambda s: None, clock=clocks.monotonic,
                     realtime=clocks.realtime, line_clock=line_clock)


@pytest.mark.parametrize('stamp_clock', ['monotonic', 'realtime'])
def test_edge_sonar_without_clock_step_measures(stamp_clock):
    sonar = _edge_sonar(_Clocks(), 5_830_000, stamp_clock)      # 5.83 ms = 1.0 m at 20 degC
    r = sonar.measure()
    assert r.status == p.STATUS_OK and r.range_m == pytest.approx(1.0, abs=0.002)
    assert sonar.edge_clock == stamp_clock and sonar.clock_steps == 0


def test_realtime_edges_across_a_wall_clock_step_are_discarded():
    # +2 s NTP step between the edges: the realtime stamps say 2.006 s (344 m): not a range.
    sonar = _edge_sonar(_Clocks(), 5_830_000, 'realtime', step_ns=2_000_000_000)
    r = sonar.measure()
    assert r.status == p.STATUS_FAULT and sonar.clock_steps == 1
    # A small backwards step would shorten the pulse into a plausible but wrong range.
    sonar = _edge_sonar(_Clocks(), 5_830_000, 'realtime', step_ns=-3_000_000)
    assert sonar.measure().status == p.STATUS_FAULT and sonar.clock_steps == 1


def test_monotonic_edges_are_immune_to_a_wall_clock_step():
    sonar = _edge_sonar(_Clocks(), 5_830_000, 'monotonic', step_ns=2_000_000_000,
                        line_clock='monotonic')
    r = sonar.measure()
    assert r.status == p.STATUS_OK and r.range_m == pytest.approx(1.0, abs=0.002)
    assert sonar.clock_steps == 0


def test_unknown_line_clock_near_boot_discards_across_a_step():
    # No RTC: the wall clock starts near the monotonic one, so the stamps cannot tell which
    # clock they are; a step across the pulse still discards the reading.
    sonar = _edge_sonar(_Clocks(offset_ns=3_000_000), 5_830_000, 'realtime', step_ns=-2_000_000)
    assert sonar.measure().status == p.STATUS_FAULT and sonar.clock_steps == 1


def test_request_monotonic_edges_reports_failure_without_cdev():
    from m4k_drivers.sonar.real import request_monotonic_edges
    assert request_monotonic_edges(_Line()) is False      # no line fd: guard instead
