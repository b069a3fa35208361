"""The README is a front door that holds: short, linked, quoting the artifacts, real commands.

* At most 25 000 characters; every relative link of the README and of the pages it sends a
  reader to first (the lab notebook docs/results/README.md, docs/using.md) resolves, anchors
  included.
* The figures the README and the lab notebook quote are the artifacts' (tools/readme_results.py
  renders them; this is its ``--check``).
* Every command in a ``bash`` block of the README resolves: ``make`` targets and the variables
  given to them exist in the Makefile; ``ros2 run`` names an executable the package installs and
  every ``--option`` written after it is in that executable's ``--help``; the console scripts
  likewise; ``ros2 launch`` names a launch file that declares every ``name:=`` argument; files
  and test paths exist; the rest is a short list of outside tools, each named with why.
  That is "the command resolves", not "a test runs it": the commands that start the whole
  stack (``make run``, ``bringup``) are run by test_bringup / test_stack_e2e, the overlay block
  by test_real_backends_e2e, but this module does not prove the pairing line by line.
"""

import os
import re
import shlex
import subprocess
import sys

import pytest
from wsenv import ROOT

sys.path.insert(0, os.path.join(ROOT, 'tools'))
import readme_results  # noqa: E402

README = os.path.join(ROOT, 'README.md')
PAGES = [README, readme_results.NOTEBOOK, os.path.join(ROOT, 'docs', 'using.md')]
LIMIT = 25_000

# Programs the README shows that m4k does not provide, and why each is fine to show.
_OUTSIDE = {
    'export': 'shell builtin (DDS settings)',
    'colcon': 'the ROS build tool (requirements.txt installs it)',
    'ssh': 'the tunnel to the live view',
    'pytest': 'the test runner (requirements.txt)',
}


def _text(path: str) -> str:
    with open(path, encoding='utf-8') as f:
        return f.read()


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    s = re.sub(r'[^\w\- ]', '', heading.strip().lower())
    return s.replace(' ', '-')


def _anchors(path: str) -> set[str]:
    return {_slug(m) for m in re.findall(r'(?m)^#+ (.*)$', _text(path))}


def test_the_readme_is_at_most_25000_characters():
    n = len(_text(README))
    assert n <= LIMIT, f'README.md has {n} characters (limit {LIMIT}): move detail to docs/'


def test_the_quoted_figures_are_the_artifacts():
    for path in readme_results.BLOCKS:
        stale = readme_results.stale_blocks(path, _text(path))
        assert stale == [], (f'{os.path.relpath(path, ROOT)}: blocks {stale} differ from the '
                             'artifacts; run python tools/readme_results.py')


def test_the_checker_sees_a_hand_edited_figure():
    text = _text(README)
    edited = text.replace(' contacts, ', ' contact, ', 1)
    assert edited != text
    assert readme_results.stale_blocks(README, edited) == ['results-summary']


@pytest.mark.parametrize('page', PAGES, ids=lambda p: os.path.relpath(p, ROOT))
def test_every_relative_link_resolves(page):
    bad = []
    for target in re.findall(r'\]\(([^)\s]+)\)', _text(page)):
        if '://' in target or target.startswith('mailto:'):
            continue
        path, _, anchor = target.partition('#')
        full = os.path.normpath(os.path.join(os.path.dirname(page), path)) if path else page
        if not os.path.exists(full):
            bad.append(target)
        elif anchor and full.endswith('.md') and anchor not in _anchors(full):
            bad.append(target)
    assert bad == [], f'{os.path.relpath(page, ROOT)}: links that do not resolve: {bad}'


# --- the commands -------------------------------------------------------------------------------

def _commands(text: str) -> list[str]:
    """Return every command line of the ``bash`` blocks (comments and here-documents cut)."""
    out = []
    for block in re.findall(r'```bash\n(.*?)```', text, re.S):
        lines = iter(block.splitlines())
        for line in lines:
            line = line.split(' #', 1)[0].strip() if not line.lstrip().startswith('#') else ''
            if not line:
                continue
            here = re.search(r"<<-?\s*'?(\w+)'?", line)
            if here:
                for body in lines:
                    if body.strip() == here.group(1):
                        break
            out.append(line)
    return out


def _make_targets() -> tuple[set[str], set[str]]:
    text = _text(os.path.join(ROOT, 'Makefile'))
    targets = set(re.findall(r'(?m)^([\w.-]+):', text))
    variables = set(re.findall(r'\$\(([A-Z_]+)\)', text))
    return targets, variables


def _console_scripts() -> dict[str, str]:
    """Return console script -> package, from every package's setup.py."""
    out = {}
    for pkg in os.listdir(os.path.join(ROOT, 'src')):
        setup = os.path.join(ROOT, 'src', pkg, 'setup.py')
        if os.path.exists(setup):
            for name in re.findall(r"'(\w+) = [\w.]+:\w+'", _text(setup)):
                out[name] = pkg
    return out


def _help(script: str, tmp_path) -> str:
    env = dict(os.environ, M4K_RUNTIME_DIR=str(tmp_path))
    r = subprocess.run([script, '--help'], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, f'{script} --help: exit {r.returncode}\n{r.stderr[-2000:]}'
    return r.stdout


def _options(words: list[str]) -> list[str]:
    opts = []
    for w in words:
        if w == '--ros-args':
            break                       # ROS arguments: rcl's, not the executable's
        if w.startswith('--'):
            opts.append(w.split('=', 1)[0])
    return opts


def test_the_command_reader_cuts_comments_and_here_documents():
    text = ("```bash\nsource tools/env.sh   # the venv\npython - <<'EOF'  # drive\n"
            "import rclpy\nEOF\n# a comment\nrt_stat --watch\n```\n")
    assert _commands(text) == ['source tools/env.sh', "python - <<'EOF'", 'rt_stat --watch']


def test_every_readme_command_resolves(tmp_path):
    targets, variables = _make_targets()
    scripts = _console_scripts()
    commands = _commands(_text(README))
    assert 'make run' in commands and 'make test' in commands
    problems, helps = [], {}

    def check_script(script: str, args: list[str]) -> None:
        if script not in scripts:
            problems.append(f'{script}: no package installs this console script')
            return
        missing = [o for o in _options(args)
                   if o not in helps.setdefault(script, _help(script, tmp_path))]
        if missing:
            problems.append(f'{script}: options not in its --help: {missing}')

    for line in commands:
        words = shlex.split(line.split('<<', 1)[0])
        cmd, args = words[0], words[1:]
        if cmd == 'make':
            for a in args:
                if '=' in a:
                    if a.split('=', 1)[0] not in variables:
                        problems.append(f'{line}: the Makefile reads no {a.split("=")[0]}')
                elif a not in targets:
                    problems.append(f'{line}: no make target {a}')
        elif cmd == 'source':
            if not args[0].startswith('/opt/ros/') and not os.path.exists(
                    os.path.join(ROOT, args[0])):
                problems.append(f'{line}: {args[0]} does not exist')
        elif cmd == 'python':
            if args != ['-']:
                problems.append(f'{line}: only a here-document python is expected')
        elif cmd == 'ros2' and args[0] == 'run':
            pkg, exe = args[1], args[2]
            if scripts.get(exe) != pkg:
                problems.append(f'{line}: {pkg} installs no executable {exe}')
            else:
                check_script(exe, args[3:])
        elif cmd == 'ros2' and args[0] == 'launch':
            launch = os.path.join(ROOT, 'src', args[1], 'launch', args[2])
            if not os.path.exists(launch):
                problems.append(f'{line}: no launch file {args[1]}/launch/{args[2]}')
            else:
                # Every name:= of the bash blocks, comments included ([config:=...]).
                declared = set(re.findall(r"DeclareLaunchArgument\('(\w+)'", _text(launch)))
                given = set(re.findall(r'(\w+):=', ''.join(
                    re.findall(r'```bash\n(.*?)```', _text(README), re.S))))
                if given - declared:
                    problems.append(f'{line}: undeclared launch arguments '
                                    f'{sorted(given - declared)}')
        elif cmd in _OUTSIDE:
            if cmd == 'pytest':
                paths = [a for a in args if '/' in a]
                problems += [f'{line}: no {p}' for p in paths
                             if not os.path.exists(os.path.join(ROOT, p))]
        else:
            check_script(cmd, args)
    assert problems == [], '\n'.join(problems)


def test_the_readme_shows_no_command_that_was_removed():
    # issue 32: `python -m m4k_rt.schema --markdown` had stopped existing (config_doc does it).
    text = _text(README)
    assert 'm4k_rt.schema --markdown' not in text
    for mod in re.findall(r'python -m ([\w.]+)', text):
        assert os.path.exists(os.path.join(ROOT, 'src', mod.split('.')[0],
                                           *mod.split('.'))) or os.path.exists(
            os.path.join(ROOT, 'src', mod.split('.')[0], *mod.split('.')) + '.py'), mod
    for make in re.findall(r'`make (\w+)', text):
        assert make in _make_targets()[0], f'README names make {make}'
