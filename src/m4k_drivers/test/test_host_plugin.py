"""The driver host names no device: a device kind from outside is served like a built-in one.

``toy_device`` (next to this file) is a device package the host has never heard of: handler,
backend and service registered through :mod:`m4k_drivers.registry`.  A real ``driver_host``
process loads it with ``--device-module`` and a configuration, and the test plays the RT side
on a real XDDP port; the register file is the device's ground truth.
"""

import ast
import importlib
import os
import re
import sys
import time

import pytest
from rt_side import recv_kind, wait_linked

from m4k_drivers import host, registry
from m4k_rt import protocol
from m4k_rt.channel import rt_xddp_bind

pytestmark = pytest.mark.e2e  # starts processes / ROS nodes: the end-to-end tier

HERE = os.path.dirname(os.path.abspath(__file__))
K = protocol.Kind
BUILT_IN = ('motor', 'imu', 'sonar', 'led', 'lrf')


def _docstrings(tree):
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def _names_a_kind(identifier):
    # Split snake_case and CamelCase into words: _serve_motor, MotorHandler, PATH_KEYS...
    words = re.findall(r'[A-Z]?[a-z0-9]+|[A-Z]+(?![a-z])', identifier)
    return any(w.lower() in BUILT_IN or w.lower().rstrip('s') in BUILT_IN for w in words)


def test_host_code_names_no_device_kind():
    tree = ast.parse(open(host.__file__, encoding='utf-8').read())
    docs = _docstrings(tree)
    found = []
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and id(node) not in docs:
            names = [node.value] if node.value in BUILT_IN else []
        elif isinstance(node, ast.Name):
            names = [node.id]
        elif isinstance(node, ast.Attribute):
            names = [node.attr]
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names = [node.name]
        elif isinstance(node, ast.alias):
            names = [node.name, node.asname or '']
        for name in names:
            if _names_a_kind(name):
                found.append((getattr(node, 'lineno', '?'), name))
    assert found == [], f'host.py names device kinds: {found}'


def test_the_check_would_see_a_kind_switch():
    # The same walk over a snippet of the old host: a kind comparison and a per-kind method.
    tree = ast.parse("if self.kind == 'motor':\n    self._serve_lrf(msg)\n")
    consts = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)]
    attrs = [n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)]
    assert 'motor' in consts and '_serve_lrf' in attrs
    assert _names_a_kind('_serve_lrf') and _names_a_kind('MotorHandler')
    assert _names_a_kind('motors') and not _names_a_kind('enabled')


def test_every_built_in_kind_registers_a_service():
    for kind in BUILT_IN:
        spec = registry.service(kind)
        assert spec.accepts and callable(spec.serve) and spec.format is not None
    assert registry.service('motor').accepts == {K.WHEEL_CMD}
    assert registry.service('led').accepts == {K.LED}
    assert registry.service('motor').jog is not None and registry.service('imu').jog is None


def _env():
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (HERE, env.get('PYTHONPATH')) if p)
    return env


def _config(tmp_path, port):
    reg = tmp_path / 'register'
    reg.write_text('7\n')
    cfg = tmp_path / 'toy.yaml'
    cfg.write_text(f'devices:\n  toy:\n    backend: real\n    xddp_port: {port}\n'
                   f'    path: {reg}\n    poll_s: 0.02\n')
    return str(cfg), reg


def _wait(pred, timeout=10.0, what='condition'):
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, f'{what} not reached within {timeout} s'
        time.sleep(0.01)


def test_a_device_from_outside_is_served_end_to_end(procs, m4k_runtime_dir, tmp_path):
    cfg, reg = _config(tmp_path, 20)
    rt = rt_xddp_bind(20, runtime_dir=m4k_runtime_dir)
    proc = procs.start(['python', '-m', 'm4k_drivers.host', '--device-module', 'toy_device',
                        '--config', cfg], env=_env())
    try:
        wait_linked(rt, 30)
        status = recv_kind(rt, K.DEVICE_STATUS)
        assert status.device == 'toy' and status.state == protocol.DeviceState.ACTIVE
        assert reg.read_text() == '0\n'           # configure: register at the safe value
        rt.send(protocol.encode(K.REQUEST, 1, time.monotonic_ns(), 41, 1234))
        reply = recv_kind(rt, K.REQUEST)
        assert reply == protocol.Request(41, 1234) and reg.read_text() == '1234\n'
        # A kind the service does not take is dropped: no reply, register untouched.
        rt.send(protocol.encode(K.LED, 2, time.monotonic_ns(), 1, 2, 3, 4, 0))
        rt.send(protocol.encode(K.REQUEST, 3, time.monotonic_ns(), 42, 99))
        assert recv_kind(rt, K.REQUEST) == protocol.Request(42, 99)
        # The RT side goes away: the link-loss hook makes the output safe at once.
        rt.close()
        _wait(lambda: reg.read_text() == '0\n', what='safe register after RT loss')
        reg.write_text('5\n')
        rt = rt_xddp_bind(20, runtime_dir=m4k_runtime_dir)
        wait_linked(rt, 30)
        rt.send(protocol.encode(K.REQUEST, 4, time.monotonic_ns(), 43, 77))
        assert recv_kind(rt, K.REQUEST) == protocol.Request(43, 77)
        assert procs.stop(proc) == 0
    finally:
        procs.stop(proc)
        rt.close()
    assert reg.read_text() == '0\n'               # deactivate on SIGTERM: safe again


def test_a_device_from_outside_prints_with_its_format_and_port_sets_its_path(
        procs, tmp_path):
    cfg, reg = _config(tmp_path, 21)
    other = tmp_path / 'other-register'
    other.write_text('3\n')
    proc = procs.start(['python', '-m', 'm4k_drivers.host', '--config', cfg, '--device', 'toy',
                        '--port', str(other), '--print', '--count', '2', '--rate', '50'],
                       env=dict(_env(), M4K_DEVICE_MODULES='toy_device'))
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    # configure wrote the safe value into the file --port named, not the configured one
    assert out.splitlines() == ['toy value=0', 'toy value=0']
    assert reg.read_text() == '7\n'


def test_a_device_module_that_does_not_import_is_a_usage_error(procs):
    proc = procs.start(['python', '-m', 'm4k_drivers.host', '--device-module', 'no_such_dev'],
                       env=_env())
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert re.search(r"driver_host: cannot import device module 'no_such_dev': No module", err)


@pytest.fixture
def toy_kind(monkeypatch):
    """Register kind ``toy`` in this process for one test; the registry is restored after."""
    for name, copy in (('KIND_MODULES', dict), ('_BACKENDS', dict), ('_SERVICES', dict),
                       ('_LOADED', set)):
        monkeypatch.setattr(registry, name, copy(getattr(registry, name)))
    sys.modules.pop('toy_device', None)
    importlib.import_module('toy_device')
    yield 'toy'
    sys.modules.pop('toy_device', None)


def test_a_reply_the_wire_cannot_carry_is_counted_and_the_service_goes_on(
        toy_kind, m4k_runtime_dir, tmp_path):
    import threading

    from m4k_drivers import config as dconfig
    from m4k_drivers.handler import State
    cfg_path, reg = _config(tmp_path, 22)
    section = dconfig.validate(dconfig.load_file(cfg_path)).devices['toy']
    handler = registry.create('toy', section, registry.BuildContext())
    stop = threading.Event()
    rt = rt_xddp_bind(22, runtime_dir=m4k_runtime_dir)
    svc = host.DeviceService('toy', handler, section, 22, stop, m4k_runtime_dir)
    svc.start()
    try:
        wait_linked(rt, 10)
        _wait(lambda: handler.state == State.ACTIVE, what='active')
        reg.write_text(f'{2 ** 40}\n')            # a value REQUEST.arg (u32) cannot carry
        rt.send(protocol.encode(K.REQUEST, 1, time.monotonic_ns(), 1, 0))
        _wait(lambda: svc.encode_errors == 1, what='encode error counted')
        rt.send(protocol.encode(K.REQUEST, 2, time.monotonic_ns(), 2, 5))
        assert recv_kind(rt, K.REQUEST) == protocol.Request(2, 5)
        assert svc.thread.is_alive() and svc.served == 2
        assert handler.ticks > 0                   # the spec's tick ran while active
    finally:
        stop.set()
        svc.thread.join(5)
        rt.close()
    assert handler.state == State.FINALIZED and reg.read_text() == '0\n'


def test_the_toy_kind_is_gone_after_its_test():
    assert 'toy' not in registry.kinds()
