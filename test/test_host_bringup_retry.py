"""A device missing when the driver host starts is retried until it appears, never given up.

Until this test, the host's bring-up backoff computed its whole delay table (a million
entries of ``0.5 * 2**k``) on the first failure; ``2.0 ** 1024`` overflows, so the first failed
bring-up of any device crashed its service thread for good ("service crashed; making outputs
safe") and the device never came up, even after it appeared. Real processes: driver_host
started before sim_robot (the devices' sim-bus peer), then sim_robot.
"""

import signal
import subprocess

from wsenv import LineWatch, stack_env, start_sim_robot

from m4k_drivers.handler import RetryPolicy

TIMEOUT_S = 60.0  # bounds on waiting for lines; a healthy run needs a few seconds


def test_backoff_delay_is_defined_for_any_attempt():
    p = RetryPolicy(attempts=0, base_s=0.5, factor=2.0, max_s=10.0)
    assert [p.delay(k) for k in range(7)] == [0.5, 1.0, 2.0, 4.0, 8.0, 10.0, 10.0]
    assert p.delay(1024) == 10.0 and p.delay(10 ** 9) == 10.0   # 2.0 ** 1024 overflows
    assert RetryPolicy(attempts=4, base_s=0.02).delays() == [0.02, 0.04, 0.08]


def test_a_device_missing_at_start_comes_up_when_it_appears(procs, m4k_runtime_dir):
    env = stack_env(m4k_runtime_dir)
    host = procs.start(['python', '-m', 'm4k_drivers.host', '--runtime-dir', m4k_runtime_dir,
                        '--device', 'imu', '--device', 'sonar'], env=env,
                       stdout=subprocess.DEVNULL)
    lines = LineWatch(host.stderr, TIMEOUT_S)
    # No simulator yet: each device's bring-up fails and is retried with backoff (0.5 s, 1 s).
    for dev in ('imu', 'sonar'):
        lines.wait_for('{}: bring-up failed (retry in'.format(dev), 2)
    assert lines.count('service crashed') == 0, ''.join(lines.lines)[-3000:]
    assert host.poll() is None
    # The devices appear: both come up without restarting the host.
    start_sim_robot(procs, env, m4k_runtime_dir)
    for dev in ('imu', 'sonar'):
        lines.wait_for('{}: active'.format(dev))
    host.send_signal(signal.SIGTERM)
    assert host.wait(TIMEOUT_S) == 0
    text = lines.close()
    assert 'service crashed' not in text, text[-3000:]
    assert 'driver_host: stopped (SIGTERM); outputs safe' in text
