"""The layering the packages state, checked on what a fresh interpreter actually loads.

* The RT side -- every module of ``m4k_rt`` except the ROS bridge and bringup -- never loads
  rclpy, the rosidl runtime or any ROS interface package, directly or through another module.
  That is the Python analogue of Xenomai's "no Linux call in primary mode": a task body that
  touched ROS would take the GIL for milliseconds on the ROS side's behalf.
* The pure protocol modules of ``m4k_drivers`` (SCIP 2.0, myAHRS+ registers, AS5045/MCP4911
  words, US-100 pulses, LED colour) load no transport (pyserial, python-periphery, smbus2,
  spidev) and no ROS: the same code runs against the real device and the simulator.
* The pure parts of the bridge are tested without a ROS context: ``bridge.health`` (outages,
  counters, the link / cmd_vel / device status inputs) loads no ROS at all;
  ``bridge.diagnostics`` (RtMonitor) builds RtStatus and DiagnosticStatus, so it loads those
  interface packages (plain rosidl classes), but never rclpy.

Each module is imported in its own interpreter and ``sys.modules`` is inspected, so an import
hidden three modules deep is found too. Modules are discovered by walking the packages, so a
new module is covered without editing this file.
"""

from concurrent.futures import ThreadPoolExecutor
import json
import os
import subprocess
import sys

import pytest
from wsenv import ROOT, stack_env

_RT_PKG = os.path.join(ROOT, 'src', 'm4k_rt', 'm4k_rt')
_DRV_PKG = os.path.join(ROOT, 'src', 'm4k_drivers', 'm4k_drivers')
# The ROS face of m4k_rt: allowed to speak ROS.
_RT_ROS_FACE = ('m4k_rt.bridge', 'm4k_rt.bag', 'm4k_rt.tools.bringup')
_PROTOCOL_MODULES = ('m4k_drivers.lrf.scip', 'm4k_drivers.imu.protocol',
                     'm4k_drivers.motors.protocol', 'm4k_drivers.sonar.protocol',
                     'm4k_drivers.led.protocol')
_TRANSPORTS = ('serial', 'periphery', 'smbus2', 'spidev')
_ROS_RUNTIME = ('rclpy', 'rpyutils', 'launch', 'launch_ros')

_PROBE = r"""
import importlib, json, sys
importlib.import_module(sys.argv[1])
print(json.dumps(sorted(sys.modules)))
"""


def _modules(pkg_dir: str, pkg: str) -> list[str]:
    out = []
    for dirpath, dirnames, filenames in os.walk(pkg_dir):
        dirnames[:] = [d for d in dirnames if d != '__pycache__']
        rel = os.path.relpath(dirpath, pkg_dir)
        prefix = pkg if rel == '.' else pkg + '.' + rel.replace(os.sep, '.')
        for f in sorted(filenames):
            if f.endswith('.py'):
                out.append(prefix if f == '__init__.py' else f'{prefix}.{f[:-3]}')
    return sorted(out)


def _is_ros(name: str) -> bool:
    top = name.split('.')[0]
    return (top in _ROS_RUNTIME or top.startswith('rosidl')
            or top.endswith(('_msgs', '_srvs', '_interfaces', '_actions')))


def _is_ros_runtime(name: str) -> bool:
    return name.split('.')[0] in _ROS_RUNTIME


def _is_transport(name: str) -> bool:
    return name.split('.')[0] in _TRANSPORTS


def _loaded_by(modules: list[str], tmp_path) -> dict[str, list[str]]:
    env = stack_env(str(tmp_path))

    def probe(mod: str) -> tuple[str, list[str]]:
        r = subprocess.run([sys.executable, '-c', _PROBE, mod], env=env, capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 0, f'importing {mod} failed:\n{r.stderr}'
        return mod, json.loads(r.stdout.strip().splitlines()[-1])

    with ThreadPoolExecutor(max_workers=4) as pool:
        return dict(pool.map(probe, modules))


def _rt_side() -> list[str]:
    return [m for m in _modules(_RT_PKG, 'm4k_rt')
            if not any(m == f or m.startswith(f + '.') for f in _RT_ROS_FACE)]


def test_module_discovery_sees_the_rt_core_and_the_ros_face():
    everything = _modules(_RT_PKG, 'm4k_rt')
    assert 'm4k_rt.rt_core' in everything and 'm4k_rt.bridge.node' in everything
    rt = _rt_side()
    assert 'm4k_rt.rt_core' in rt and 'm4k_rt.xddp' in rt and 'm4k_rt.protocol' in rt
    assert not [m for m in rt if m.startswith('m4k_rt.bridge')]


def test_the_classifiers_tell_ros_and_transports_apart():
    assert _is_ros('rclpy.node') and _is_ros('geometry_msgs.msg') and _is_ros('m4k_msgs')
    assert _is_ros('rosidl_parser') and _is_ros('rcl_interfaces.msg')
    assert not _is_ros('m4k_rt.protocol') and not _is_ros('struct')
    assert _is_transport('serial.tools') and _is_transport('periphery')
    assert not _is_transport('m4k_drivers.lrf.scip')
    assert _is_ros_runtime('rclpy.node') and not _is_ros_runtime('diagnostic_msgs.msg')


def test_the_probe_sees_an_import_made_through_another_module(tmp_path):
    # The bridge node loads rclpy only through its own imports: the probe must see it.
    loaded = _loaded_by(['m4k_rt.bridge.node'], tmp_path)['m4k_rt.bridge.node']
    assert 'rclpy' in loaded and 'm4k_msgs' in loaded


def test_no_module_of_the_rt_side_loads_ros(tmp_path):
    loaded = _loaded_by(_rt_side(), tmp_path)
    offenders = {m: sorted({n.split('.')[0] for n in names if _is_ros(n)})
                 for m, names in loaded.items()}
    offenders = {m: ros for m, ros in offenders.items() if ros}
    assert offenders == {}, f'RT-side modules that load ROS: {offenders}'


@pytest.mark.parametrize('module', _PROTOCOL_MODULES)
def test_a_pure_protocol_module_loads_no_transport_and_no_ros(module, tmp_path):
    names = _loaded_by([module], tmp_path)[module]
    bad = sorted({n.split('.')[0] for n in names if _is_ros(n) or _is_transport(n)})
    assert bad == [], f'{module} loads {bad}'


# The bridge's pure modules and what each must not load.
_BRIDGE_PURE = {'m4k_rt.bridge.health': _is_ros, 'm4k_rt.bridge.diagnostics': _is_ros_runtime}


@pytest.mark.parametrize('module', sorted(_BRIDGE_PURE))
def test_the_bridge_bookkeeping_needs_no_ros_context(module, tmp_path):
    assert module in _modules(_RT_PKG, 'm4k_rt')
    names = _loaded_by([module], tmp_path)[module]
    bad = sorted({n.split('.')[0] for n in names if _BRIDGE_PURE[module](n)})
    assert bad == [], f'{module} loads {bad}'
