"""``bringup_check``: run the first-power checks of the configured real devices, write a report.

    bringup_check --overlay my_robot.yaml [--steps spi,i2c,gpio,sonar,amp,urg]
                  [--report bringup-check.json]

Each step names what it expects and what a failure means (:mod:`m4k_drivers.bringup.steps`);
the report file holds the same, one record per step, and the exit code is 0 only when every
step that ran passed (1: a step failed; 2: a bad configuration or option).  Steps whose device
is not configured with a real backend are skipped and listed as such.  Before the ``spi`` step
put a jumper from MOSI to MISO on each bus and unplug the devices on MISO (the AS5045s on
SPI1); before ``sonar`` point the US-100 at open space; ``amp`` runs with the motor supply off.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any, Callable

from m4k_drivers.bringup import steps as st

__all__ = ['STEPS', 'main', 'run']

STEPS = ('spi', 'i2c', 'gpio', 'sonar', 'amp', 'urg')


def _real(devices: dict[str, Any], kind: str, backends: tuple[str, ...] = ('real',)
          ) -> dict[str, Any] | None:
    s = devices.get(kind)
    return s if s and s.get('enabled', True) and s.get('backend') in backends else None


def run(devices: dict[str, Any], wanted: tuple[str, ...] = STEPS, *,
        sleep: Callable[[float], None] = time.sleep) -> list[st.StepResult]:
    """Run the ``wanted`` steps for the validated ``devices`` sections; return the results."""
    out: list[st.StepResult] = []
    m = _real(devices, 'motor')
    led = _real(devices, 'led', ('pixel_spi',))
    if 'spi' in wanted and m is not None:
        out.append(st.spi_loopback(m['left_dac'], m['dac_mode'], m['dac_speed_hz']))
        out.append(st.spi_loopback(m['left_enc'], m['enc_mode'], m['enc_speed_hz']))
    if 'spi' in wanted and led is not None:
        out.append(st.spi_loopback(led['device'], 0, led['spi_hz']))
    imu = _real(devices, 'imu')
    if 'i2c' in wanted and imu is not None:
        out.append(st.i2c_who_am_i(imu['bus'], imu['address']))
    if 'gpio' in wanted and m is not None and m['heartbeat'] \
            and m['estop_readback_line'] is not None:
        out.append(st.gpio_loopback(
            m['heartbeat_chip'], m['heartbeat_line'], m['estop_readback_chip'],
            m['estop_readback_line'], active_low=m['estop_readback_active'] == 'low',
            hold_s=m['heartbeat_hold_s'], period_s=m['period_s'], sleep=sleep))
    sonar = _real(devices, 'sonar', ('real', 'gpio'))
    if 'sonar' in wanted and sonar is not None:
        out.append(st.sonar_no_echo(sonar['chip'], sonar['trigger_line'], sonar['echo_line'],
                                    no_echo_s=sonar['no_echo_s'],
                                    timeout_s=sonar['timeout_s']))
    if 'amp' in wanted and m is not None:
        out.append(st.amp_hold(m, sleep=sleep))
    lrf = _real(devices, 'lrf')
    if 'urg' in wanted and lrf is not None:
        out.append(st.urg_version(lrf['port']))
    return out


def write_report(results: list[st.StepResult], path: str, skipped: list[str]) -> None:
    """Write the report file: every step's expectation, verdict, detail and failure meaning."""
    doc = {'tool': 'bringup_check', 'time': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
           'passed': all(r.passed is not False for r in results),
           'steps': [r.as_dict() for r in results], 'skipped': skipped}
    with open(path, 'w', encoding='utf-8') as fh:
        json.dump(doc, fh, indent=2)
        fh.write('\n')


def main(argv: list[str] | None = None) -> int:
    """Run the checks of the layered configuration; print and write the report."""
    from m4k_drivers import config as dconfig
    from m4k_drivers.host import load_raw_config
    from m4k_rt import rosargs
    ap = argparse.ArgumentParser(prog='bringup_check', description=__doc__.split('\n')[0])
    ap.add_argument('--config', help='one config file instead of the layered configuration')
    ap.add_argument('--overlay', help='overlay YAML (your robot)')
    ap.add_argument('--steps', default=','.join(STEPS), help=f'subset of {",".join(STEPS)}')
    ap.add_argument('--report', default='bringup-check.json', help='report file (JSON)')
    args = rosargs.parse_args(ap, argv)
    wanted = tuple(s for s in args.steps.split(',') if s)
    unknown = [s for s in wanted if s not in STEPS]
    try:
        if unknown:
            raise ValueError(f'--steps: unknown {unknown!r}; choose from {",".join(STEPS)}')
        raw = load_raw_config(args.config, args.overlay)
        devices = {kind: dconfig.validate_device(kind, section, f'devices.{kind}')
                   for kind, section in (raw.get('devices') or {}).items()
                   if kind in ('motor', 'imu', 'sonar', 'lrf', 'led')}
    except (dconfig.ConfigError, ValueError) as exc:
        print(f'bringup_check: {exc}', file=sys.stderr)
        return 2
    results = run(devices, wanted)
    ran = {{'amplifier': 'amp'}.get(w, w) for w in (r.step.split()[0] for r in results)}
    skipped = [s for s in wanted if s not in ran]
    for r in results:
        verdict = {True: 'PASS', False: 'FAIL', None: 'MANUAL'}[r.passed]
        print(f'{verdict:6s} {r.step}: {r.detail}')
        print(f'       expects: {r.expect}')
        if r.passed is False:
            print(f'       a failure means: {r.failure_means}')
    for s in skipped:
        print(f'SKIP   {s}: no device configured with a real backend for it')
    write_report(results, args.report, skipped)
    print(f'report: {args.report}')
    return 0 if all(r.passed is not False for r in results) else 1


if __name__ == '__main__':
    raise SystemExit(main())
