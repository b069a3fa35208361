"""The layering the packages state, checked on what a fresh interpreter actually loads.

* **No ROS below the bridge.** Every module of ``m4k_rt`` (the RT core) and ``m4k_drivers``
  (the driver host, the device handlers, sim_robot) never loads rclpy, launch, the rosidl
  runtime or any ROS interface package, directly or through another module -- no exemption
  list. That is the Python analogue of Xenomai's "no Linux call in primary mode": a task body
  that touched ROS would take the GIL for milliseconds on the ROS side's behalf.
* **No upward import.** A module of an m4k package loads only the m4k packages its
  ``package.xml`` declares (``exec_depend``), so a wrong-way dependency needs a package.xml
  change to exist; and the declared dependencies themselves form no circle.
* The pure protocol modules of ``m4k_drivers`` (SCIP 2.0, myAHRS+ registers, AS5045/MCP4911
  words, US-100 pulses, LED colour) load no transport (pyserial, python-periphery, smbus2,
  spidev) and no ROS: the same code runs against the real device and the simulator.
* **The test machinery ships in no runtime package.** The shared fixtures live in
  ``m4k_testing`` (src/m4k_testing), which sits on top of the layering beside the tests: it may
  use any package (its process fixture starts processes as m4k_bringup's ``Child``), and no
  module of a runtime package names it, pytest or hypothesis in an import statement (lazy ones
  too) or loads them. No runtime package declares it except as a ``test_depend``, and only where
  colcon can still order the packages (colcon orders on test dependencies too); every test
  directory's conftest.py takes its fixtures from it.
* The pure parts of the bridge are tested without a ROS context: ``m4k_bridge.health`` loads no
  ROS at all; ``m4k_bridge.diagnostics`` builds RtStatus and DiagnosticStatus, so it loads those
  interface packages (plain rosidl classes), but never rclpy.

Each module is imported in its own interpreter and ``sys.modules`` is inspected, so an import
hidden three modules deep is found too; a function-local import is caught statically by ruff's
banned-import rule (``src/m4k_rt/ruff.toml``, ``src/m4k_drivers/ruff.toml``). Modules are
discovered by walking the packages, so a new module is covered without editing this file.
"""

import ast
from concurrent.futures import ThreadPoolExecutor
import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest
from wsenv import PYTHON_PACKAGES, ROOT, stack_env, TEST_PACKAGES

_PROTOCOL_MODULES = ('m4k_drivers.lrf.scip', 'm4k_drivers.imu.protocol',
                     'm4k_drivers.motors.protocol', 'm4k_drivers.sonar.protocol',
                     'm4k_drivers.led.protocol')
_TRANSPORTS = ('serial', 'periphery', 'smbus2', 'spidev')
_ROS_RUNTIME = ('rclpy', 'rpyutils', 'launch', 'launch_ros')
_ROS_FREE_PACKAGES = ('m4k_rt', 'm4k_drivers')
_M4K = PYTHON_PACKAGES + TEST_PACKAGES + ('m4k_msgs',)
# What only tests may load: the tests' package and the test frameworks.
_TEST_MACHINERY = TEST_PACKAGES + ('pytest', '_pytest', 'hypothesis')

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


_PROBED: dict[str, list[str]] = {}   # module -> what importing it loaded (probed once a run)


def _loaded_by(modules: list[str], tmp_path) -> dict[str, list[str]]:
    """Return what importing each module loads, each in a fresh interpreter.

    A module is probed once per test run: the ROS check and the declared-dependency check read
    the same probe instead of starting every interpreter twice.
    """
    env = stack_env(str(tmp_path))

    def probe(mod: str) -> tuple[str, list[str]]:
        r = subprocess.run([sys.executable, '-c', _PROBE, mod], env=env, capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 0, f'importing {mod} failed:\n{r.stderr}'
        return mod, json.loads(r.stdout.strip().splitlines()[-1])

    missing = [m for m in modules if m not in _PROBED]
    if missing:
        with ThreadPoolExecutor(max_workers=4) as pool:
            _PROBED.update(pool.map(probe, missing))
    return {m: _PROBED[m] for m in modules}


def _pkg_modules(pkg: str) -> list[str]:
    return _modules(os.path.join(ROOT, 'src', pkg, pkg), pkg)


def _declared_deps(pkg: str, tags=('depend', 'exec_depend', 'build_depend')) -> set[str]:
    root = ET.parse(os.path.join(ROOT, 'src', pkg, 'package.xml')).getroot()
    return {e.text.strip() for tag in tags for e in root.findall(tag) if e.text}


def test_module_discovery_sees_every_package_and_the_driver_host():
    rt, drv = _pkg_modules('m4k_rt'), _pkg_modules('m4k_drivers')
    assert 'm4k_rt.rt_core' in rt and 'm4k_rt.protocol' in rt
    assert {'m4k_rt.channel', 'm4k_rt.channel.port', 'm4k_rt.channel.nrt'} <= set(rt)
    assert 'm4k_drivers.host' in drv and 'm4k_drivers.sim_robot' in drv
    assert not [m for m in rt if 'bridge' in m or 'bringup' in m]
    assert 'm4k_bridge.node' in _pkg_modules('m4k_bridge')
    assert 'm4k_bringup.bringup' in _pkg_modules('m4k_bringup')


def test_the_classifiers_tell_ros_and_transports_apart():
    assert _is_ros('rclpy.node') and _is_ros('geometry_msgs.msg') and _is_ros('m4k_msgs')
    assert _is_ros('rosidl_parser') and _is_ros('rcl_interfaces.msg')
    assert not _is_ros('m4k_rt.protocol') and not _is_ros('struct')
    assert _is_transport('serial.tools') and _is_transport('periphery')
    assert not _is_transport('m4k_drivers.lrf.scip')
    assert _is_ros_runtime('rclpy.node') and not _is_ros_runtime('diagnostic_msgs.msg')


def test_the_probe_sees_an_import_made_through_another_module(tmp_path):
    # The bridge node loads rclpy only through its own imports: the probe must see it.
    loaded = _loaded_by(['m4k_bridge.node'], tmp_path)['m4k_bridge.node']
    assert 'rclpy' in loaded and 'm4k_msgs' in loaded


@pytest.mark.parametrize('pkg', _ROS_FREE_PACKAGES)
def test_no_module_of_the_rt_core_or_the_drivers_loads_ros(pkg, tmp_path):
    loaded = _loaded_by(_pkg_modules(pkg), tmp_path)
    offenders = {m: sorted({n.split('.')[0] for n in names if _is_ros(n)})
                 for m, names in loaded.items()}
    offenders = {m: ros for m, ros in offenders.items() if ros}
    assert offenders == {}, f'{pkg} modules that load ROS: {offenders}'


@pytest.mark.parametrize('pkg', PYTHON_PACKAGES)
def test_a_package_loads_only_the_m4k_packages_its_package_xml_declares(pkg, tmp_path):
    allowed = (_declared_deps(pkg) & set(_M4K)) | {pkg}
    loaded = _loaded_by(_pkg_modules(pkg), tmp_path)
    upward = {m: sorted({n.split('.')[0] for n in names} & set(_M4K) - allowed)
              for m, names in loaded.items()}
    upward = {m: pkgs for m, pkgs in upward.items() if pkgs}
    assert upward == {}, f'{pkg} modules loading undeclared m4k packages: {upward}'


def _imported_names(path: str) -> set[str]:
    """Return every module name an import statement of ``path`` names, function-local too."""
    with open(path, encoding='utf-8') as f:
        tree = ast.parse(f.read(), path)
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


@pytest.mark.parametrize('pkg', PYTHON_PACKAGES + TEST_PACKAGES)
def test_no_import_statement_names_an_undeclared_m4k_package(pkg):
    # The probe above sees what importing a module loads; a lazy import inside a function is
    # only seen here, by reading every import statement of the package's modules.
    allowed = (_declared_deps(pkg) & set(_M4K)) | {pkg}
    bad = {}
    root = os.path.join(ROOT, 'src', pkg, pkg)
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = [d for d in dirnames if d != '__pycache__']
        for f in filenames:
            if f.endswith('.py'):
                path = os.path.join(dirpath, f)
                wrong = {n.split('.')[0] for n in _imported_names(path)} & set(_M4K) - allowed
                if wrong:
                    bad[os.path.relpath(path, ROOT)] = sorted(wrong)
    assert bad == {}, f'{pkg}: imports of m4k packages its package.xml does not declare: {bad}'


def test_the_import_reader_sees_a_function_local_import(tmp_path):
    src = tmp_path / 'm.py'
    src.write_text('def f():\n    from m4k_bringup import bringup\n    import m4k_bridge.node\n')
    assert _imported_names(str(src)) == {'m4k_bringup', 'm4k_bridge.node'}


def test_the_declared_dependencies_form_no_circle():
    pkgs = PYTHON_PACKAGES + TEST_PACKAGES
    deps = {p: _declared_deps(p) & set(pkgs) for p in pkgs}
    order: list[str] = []
    while deps:
        ready = sorted(p for p, d in deps.items() if d <= set(order))
        assert ready, f'dependency circle among {sorted(deps)}: {deps}'
        order += ready
        for p in ready:
            del deps[p]
    assert order.index('m4k_rt') < order.index('m4k_drivers') < order.index('m4k_bringup')
    assert order.index('m4k_bridge') < order.index('m4k_bringup')
    assert order.index('m4k_bringup') < order.index('m4k_testing')   # on top, beside the tests


def test_the_ros_free_packages_declare_no_ros_runtime():
    for pkg in _ROS_FREE_PACKAGES:
        ros = sorted(d for d in _declared_deps(pkg) if _is_ros(d))
        assert ros == [], f'{pkg}/package.xml declares ROS runtime dependencies {ros}'


@pytest.mark.parametrize('module', _PROTOCOL_MODULES)
def test_a_pure_protocol_module_loads_no_transport_and_no_ros(module, tmp_path):
    names = _loaded_by([module], tmp_path)[module]
    bad = sorted({n.split('.')[0] for n in names if _is_ros(n) or _is_transport(n)})
    assert bad == [], f'{module} loads {bad}'


def test_the_laser_package_loads_pyserial_only_through_its_backends(tmp_path):
    # The registry imports m4k_drivers.lrf.backends; the package itself stays transport-free.
    loaded = _loaded_by(['m4k_drivers.lrf', 'm4k_drivers.lrf.backends'], tmp_path)
    assert not [n for n in loaded['m4k_drivers.lrf'] if _is_transport(n) or _is_ros(n)]
    assert 'serial' in loaded['m4k_drivers.lrf.backends']


# The bridge's pure modules and what each must not load.
_BRIDGE_PURE = {'m4k_bridge.health': _is_ros, 'm4k_bridge.diagnostics': _is_ros_runtime}


@pytest.mark.parametrize('module', sorted(_BRIDGE_PURE))
def test_the_bridge_bookkeeping_needs_no_ros_context(module, tmp_path):
    assert module in _pkg_modules('m4k_bridge')
    names = _loaded_by([module], tmp_path)[module]
    bad = sorted({n.split('.')[0] for n in names if _BRIDGE_PURE[module](n)})
    assert bad == [], f'{module} loads {bad}'


# --- the test machinery: on top, beside the tests, never in a runtime package ---------------

def _is_test_machinery(name: str) -> bool:
    return name.split('.')[0] in _TEST_MACHINERY


@pytest.mark.parametrize('pkg', PYTHON_PACKAGES)
def test_no_runtime_module_loads_the_test_machinery(pkg, tmp_path):
    loaded = _loaded_by(_pkg_modules(pkg), tmp_path)
    offenders = {m: sorted({n.split('.')[0] for n in names if _is_test_machinery(n)})
                 for m, names in loaded.items()}
    offenders = {m: t for m, t in offenders.items() if t}
    assert offenders == {}, f'{pkg} modules that load test machinery: {offenders}'


@pytest.mark.parametrize('pkg', PYTHON_PACKAGES)
def test_no_runtime_module_names_the_test_machinery_even_lazily(pkg):
    bad = {}
    for mod, path in _module_files({pkg: os.path.join(ROOT, 'src', pkg, pkg)}).items():
        named = sorted({n.split('.')[0] for n in _imported_names(path)} & set(_TEST_MACHINERY))
        if named:
            bad[mod] = named
    assert bad == {}, f'{pkg}: runtime modules importing test machinery: {bad}'


def _run_closure(pkg: str, pkgs: tuple[str, ...]) -> set[str]:
    """Return the packages ``pkg`` needs at run time, recursively (exec/build dependencies)."""
    seen: set[str] = set()
    todo = [pkg]
    while todo:
        for dep in _declared_deps(todo.pop()) & set(pkgs) - seen:
            seen.add(dep)
            todo.append(dep)
    return seen


def test_the_test_package_sits_on_top_and_no_runtime_package_needs_it():
    pkgs = PYTHON_PACKAGES + TEST_PACKAGES
    for test_pkg in TEST_PACKAGES:
        # It needs what its process fixture runs on (Child, the one process wrapper) ...
        assert 'm4k_bringup' in _declared_deps(test_pkg)
        below = _run_closure(test_pkg, pkgs)
        assert test_pkg not in below
        for pkg in PYTHON_PACKAGES:
            # ... and no runtime package needs it to run,
            assert test_pkg not in _declared_deps(pkg), f'{pkg} depends on {test_pkg}'
            # and a test_depend on it appears only where colcon can still order the
            # packages: not in a package it itself runs on (that closes a circle).
            if test_pkg in _declared_deps(pkg, ('test_depend',)):
                assert pkg not in below, (
                    f'{pkg} declares test_depend {test_pkg}, which runs on {pkg}: '
                    'colcon orders on test dependencies too, so that is a circle')


def test_the_circle_rule_for_test_depends_sees_a_circle():
    # m4k_rt below m4k_bringup, which the test package runs on: its test_depend would circle.
    assert 'm4k_rt' in _run_closure('m4k_testing', PYTHON_PACKAGES + TEST_PACKAGES)
    assert 'm4k_bench' not in _run_closure('m4k_testing', PYTHON_PACKAGES + TEST_PACKAGES)


def _test_dirs() -> list[str]:
    dirs = [os.path.join(ROOT, 'test')]
    for pkg in PYTHON_PACKAGES + TEST_PACKAGES:
        d = os.path.join(ROOT, 'src', pkg, 'test')
        if os.path.isdir(d):
            dirs.append(d)
    return dirs


def test_every_test_directory_takes_its_fixtures_from_the_test_package():
    # The leak check, the skip policy and the hypothesis profile hold in every suite.
    dirs = _test_dirs()
    assert os.path.join(ROOT, 'src', 'm4k_rt', 'test') in dirs and len(dirs) >= 6
    missing = [os.path.relpath(d, ROOT) for d in dirs
               if not os.path.isfile(os.path.join(d, 'conftest.py'))
               or 'm4k_testing' not in _imported_names(os.path.join(d, 'conftest.py'))]
    assert missing == [], f'test directories whose conftest.py does not use m4k_testing: {missing}'


# --- no import circle, not even through a function-local (lazy) import ----------------------

def _module_files(pkg_roots: dict[str, str]) -> dict[str, str]:
    """Return module name -> file for every module of the packages ``{pkg: package dir}``."""
    files = {}
    for pkg, pkg_dir in pkg_roots.items():
        for mod in _modules(pkg_dir, pkg):
            rel = mod.split('.')[1:]
            path = os.path.join(pkg_dir, *rel)
            files[mod] = (os.path.join(path, '__init__.py') if os.path.isdir(path)
                          else path + '.py')
    return files


def _import_graph(pkg_roots: dict[str, str]) -> dict[str, set[str]]:
    """Return module -> the modules of these packages that any import statement of it names.

    Every ``import`` / ``from ... import`` counts, wherever it stands (module level, inside a
    function, under ``if TYPE_CHECKING``); ``from a import b`` names ``a.b`` when that is a
    module, else ``a``; relative imports are resolved.
    """
    files = _module_files(pkg_roots)
    known = set(files)

    def resolve(name: str) -> str | None:
        while name and name not in known:
            name = name.rpartition('.')[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        with open(path, encoding='utf-8') as f:
            tree = ast.parse(f.read(), path)
        is_pkg = path.endswith('__init__.py')
        targets: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets.update(t for a in node.names if (t := resolve(a.name)))
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ''
                if node.level:
                    parts = mod.split('.')
                    anchor = parts if is_pkg else parts[:-1]
                    anchor = anchor[:len(anchor) - (node.level - 1)]
                    base = '.'.join(anchor + ([base] if base else []))
                for a in node.names:
                    t = resolve(base + '.' + a.name) if base else resolve(a.name)
                    if t:
                        targets.add(t)
        targets.discard(mod)
        graph[mod] = targets
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Return the import circles: each strongly connected set of two or more modules."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:   # Tarjan's algorithm; the graph is small (about 200 nodes)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                out.append(sorted(scc))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_module_imports_one_that_imports_it_back():
    graph = _import_graph({p: os.path.join(ROOT, 'src', p, p)
                           for p in PYTHON_PACKAGES + TEST_PACKAGES})
    assert 'm4k_rt.schema' in graph and 'm4k_bringup.configdoc' in graph
    assert 'm4k_rt.schema' in graph['m4k_rt.control.params']
    circles = _cycles(graph)
    detail = {' -> '.join(c): {m: sorted(graph[m] & set(c)) for m in c} for c in circles}
    assert circles == [], f'import circles (lazy imports included): {detail}'


def test_the_circle_finder_sees_a_lazy_import_back(tmp_path):
    pkg = tmp_path / 'pk'
    (pkg / 'sub').mkdir(parents=True)
    (pkg / '__init__.py').write_text('')
    (pkg / 'sub' / '__init__.py').write_text('')
    (pkg / 'a.py').write_text('from pk.sub import b\n')
    (pkg / 'sub' / 'b.py').write_text('def f():\n    from .. import a\n    return a\n')
    (pkg / 'c.py').write_text('import pk.a\nfrom pk.sub.b import f\n')
    graph = _import_graph({'pk': str(pkg)})
    assert graph['pk.a'] == {'pk.sub.b'} and graph['pk.sub.b'] == {'pk.a'}
    assert graph['pk.c'] == {'pk.a', 'pk.sub.b'}
    assert _cycles(graph) == [['pk.a', 'pk.sub.b']]


def test_the_tests_start_the_stack_with_bringups_one_recipe():
    # Every workspace test that starts bringup takes its command from bringup_argv, as the
    # tools do (src/m4k_bench/test/test_stack_recipe.py): no `-m m4k_bringup.bringup` spelt out.
    here = os.path.dirname(os.path.abspath(__file__))
    inline = []
    for name in sorted(os.listdir(here)):
        if not name.endswith('.py'):
            continue
        with open(os.path.join(here, name), encoding='utf-8') as f:
            tree = ast.parse(f.read())
        for node in ast.walk(tree):
            if isinstance(node, ast.List):
                words = [e.value if isinstance(e, ast.Constant) else None for e in node.elts]
                if any(a == '-m' and b == 'm4k_bringup.bringup'
                       for a, b in zip(words, words[1:], strict=False)):
                    inline.append(f'{name}:{node.lineno}')
    assert inline == []
