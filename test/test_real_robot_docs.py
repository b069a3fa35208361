"""docs/real-robot.md cites only what exists; the shipped udev rules and systemd unit parse.

A bring-up guide that names a file, a module or a console script the repository does not have
sends a new user hunting; the rules and the unit are copied to /etc as they are, so a syntax
error only shows on the robot.
"""

import configparser
import importlib.util
import os
import re
import shutil
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOC = os.path.join(ROOT, 'docs', 'real-robot.md')
RULES = os.path.join(ROOT, 'config', 'udev', '99-m4k.rules')
UNIT = os.path.join(ROOT, 'config', 'systemd', 'm4k.service')

# Repository paths start with one of the top-level directories (or are a top-level file).
_PATH = re.compile(r'(?<![\w/.-])((?:config|docs|src|test|tools|compat)/[\w./*-]*[\w*]'
                   r'|README\.md|Makefile)')
_LINK = re.compile(r'\]\(([^)#\s]+)')
_MODULE = re.compile(r'(?<![\w.])(m4k_(?:rt|drivers|bridge|bringup|bench)(?:\.\w+)+)')


def _doc() -> str:
    with open(DOC, encoding='utf-8') as f:
        return f.read()


def test_every_repository_path_the_guide_cites_exists():
    text = _doc()
    cited = set(_PATH.findall(text))
    cited |= {os.path.normpath(os.path.join('docs', link)) for link in _LINK.findall(text)
              if '://' not in link}
    assert {'config/udev/99-m4k.rules', 'config/systemd/m4k.service'} <= cited
    missing = []
    for path in sorted(cited):
        path = path.rstrip('.')
        if '*' in path:
            import glob
            if not glob.glob(os.path.join(ROOT, path)):
                missing.append(path)
        elif not os.path.exists(os.path.join(ROOT, path)):
            missing.append(path)
    assert not missing, f'docs/real-robot.md cites paths that do not exist: {missing}'


def test_every_module_the_guide_cites_imports():
    missing = []
    for name in sorted(set(_MODULE.findall(_doc()))):
        # A dotted name may end in a class or function: find the longest importable prefix.
        parts = name.split('.')
        for n in range(len(parts), 0, -1):
            mod = '.'.join(parts[:n])
            try:
                spec = importlib.util.find_spec(mod)
            except ModuleNotFoundError:
                spec = None
            if spec is not None:
                rest = parts[n:]
                if rest:
                    obj = importlib.import_module(mod)
                    for attr in rest:
                        obj = getattr(obj, attr, None)
                    if obj is None:
                        missing.append(name)
                break
        else:
            missing.append(name)
    assert not missing, f'docs/real-robot.md cites modules that do not exist: {missing}'


def _declared_scripts():
    declared = set()
    for pkg in os.listdir(os.path.join(ROOT, 'src')):
        setup = os.path.join(ROOT, 'src', pkg, 'setup.py')
        if os.path.isfile(setup):
            with open(setup, encoding='utf-8') as f:
                declared |= {(pkg, exe) for exe in re.findall(r"'(\w+) = [\w.]+:\w+'", f.read())}
    return declared


def test_every_console_script_the_guide_runs_is_declared():
    declared = _declared_scripts()
    runs = set(re.findall(r'ros2 run (\w+) (\w+)', _doc()))
    assert runs, 'the guide runs nothing with ros2 run'
    assert runs <= declared, f'not declared in any setup.py: {sorted(runs - declared)}'


# -- udev ------------------------------------------------------------------------------------
_MATCH_KEYS = {'ACTION', 'DEVPATH', 'KERNEL', 'KERNELS', 'NAME', 'SUBSYSTEM', 'SUBSYSTEMS',
               'DRIVER', 'DRIVERS', 'TAG', 'TAGS', 'PROGRAM', 'RESULT', 'TEST', 'ATTR', 'ATTRS',
               'ENV', 'SYSCTL', 'CONST'}
_ASSIGN_KEYS = {'NAME', 'SYMLINK', 'OWNER', 'GROUP', 'MODE', 'TAG', 'ENV', 'RUN', 'LABEL',
                'GOTO', 'IMPORT', 'OPTIONS', 'ATTR', 'SECLABEL', 'SYSCTL', 'WAIT_FOR'}
_TOKEN = re.compile(r'\s*([A-Z_]+)(\{[^}]+\})?\s*(==|!=|\+=|-=|:=|=)\s*"((?:[^"\\]|\\.)*)"\s*'
                    r'(,|$)')


def _rules(path):
    """Yield (line number, logical line) with continuations joined, comments dropped."""
    with open(path, encoding='utf-8') as f:
        lines = f.read().split('\n')
    buf, start = '', 0
    for i, line in enumerate(lines, 1):
        if not buf:
            start = i
        if line.endswith('\\'):
            buf += line[:-1]
            continue
        buf += line
        if buf.strip() and not buf.lstrip().startswith('#'):
            yield start, buf
        buf = ''


def _parse_rule(line):
    pos, out = 0, []
    while pos < len(line):
        m = _TOKEN.match(line, pos)
        if not m:
            raise ValueError(f'cannot parse at column {pos}: {line[pos:]!r}')
        out.append((m.group(1), m.group(2), m.group(3), m.group(4)))
        pos = m.end()
    return out


def test_udev_rules_parse_and_every_rule_matches_then_assigns():
    rules = list(_rules(RULES))
    assert rules
    groups = set()
    for lineno, line in rules:
        tokens = _parse_rule(line)
        matches = [t for t in tokens if t[2] in ('==', '!=')]
        assigns = [t for t in tokens if t[2] not in ('==', '!=')]
        assert matches and assigns, f'line {lineno}: a rule needs a match and an assignment'
        for key, _, _, _ in matches:
            assert key in _MATCH_KEYS, f'line {lineno}: {key} is not a match key'
        for key, _, _, value in assigns:
            assert key in _ASSIGN_KEYS, f'line {lineno}: {key} cannot be assigned'
            if key == 'MODE':
                assert re.fullmatch(r'0[0-7]{3}', value), f'line {lineno}: MODE={value!r}'
            if key == 'GROUP':
                groups.add(value)
            if key == 'RUN':
                assert value.split()[0].startswith('/'), f'line {lineno}: RUN needs an ' \
                    'absolute program path'
    # Every group the rules hand devices to is one the guide tells the user to create or
    # join, and the URG gets the symlink the guide configures.
    text = _doc()
    joined = re.search(r'usermod -aG ([\w,]+) "\$USER"', text)
    assert joined, 'the guide does not say which groups to join'
    assert groups <= set(joined.group(1).split(',')), (groups, joined.group(1))
    created = set(re.findall(r'groupadd -f (\w+)', text))
    assert groups - {'dialout'} <= created, f'groups never created: {groups - created}'
    assert '/dev/urg04lx' in text and 'SYMLINK+="urg04lx"' in open(RULES).read()


def test_a_broken_rule_is_caught_by_the_parser():
    with pytest.raises(ValueError, match='cannot parse'):
        _parse_rule('SUBSYSTEM=="tty", GROUP=dialout')


# -- systemd ---------------------------------------------------------------------------------
def test_systemd_unit_verifies():
    analyze = shutil.which('systemd-analyze')
    if analyze is not None:
        r = subprocess.run([analyze, 'verify', UNIT], capture_output=True, text=True,
                           timeout=60)
        assert r.returncode == 0 and not r.stderr.strip(), r.stderr
    # Structure (also without systemd): the sections, an absolute ExecStart, a target.
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.optionxform = str
    cp.read(UNIT)
    assert {'Unit', 'Service', 'Install'} <= set(cp.sections())
    exec_start = cp['Service']['ExecStart']
    assert exec_start.startswith('/'), exec_start
    assert cp['Install']['WantedBy'] == 'multi-user.target'
    # What the stack needs to run as an ordinary user: the groups of the udev rules and the
    # RT limits (README: rtprio 95, memlock unlimited).
    assert set(cp['Service']['SupplementaryGroups'].split()) >= {'dialout', 'spi', 'i2c',
                                                                 'gpio', 'leds'}
    assert cp['Service']['LimitRTPRIO'] == '95' and cp['Service']['LimitMEMLOCK'] == 'infinity'
    # It starts what the repository ships: tools/env.sh, then a declared console script.
    m = re.search(r'source /opt/m4k/(\S+) && exec (\w+) ', exec_start)
    assert m, exec_start
    assert os.path.isfile(os.path.join(ROOT, m.group(1)))
    assert m.group(2) in {exe for _, exe in _declared_scripts()}
