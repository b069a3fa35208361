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
    (0.0001, 20.0, 0.01716, p.STATUS_NO_ECHO),         # 1.7 cm < 2 cm
    (0.038, 20.0, 6.5211, p.STATUS_NO_ECHO),           # the long no-echo pulse
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


class FakeClock:
    def __init__(self):
        self.t = 0

    def __call__(self):
        return self.t

    def sleep(self, s):
        self.t += int(s * 1e9)


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


def test_sim_sonar_no_echo_beyond_max_range():
    world, clock, sonar = _sim(WorldConfig(walls=((6.0, -3.0, 6.0, 3.0),), obstacles=()))
    assert sonar.measure().status == p.STATUS_NO_ECHO


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
    assert dev.measure().status == p.STATUS_NO_ECHO
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
