"""What workspace tests share: the repository root and the environment of stack processes."""

import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def stack_env(runtime_dir: str) -> dict[str, str]:
    """Return the environment for stack processes run from the source tree.

    The sources come first on PYTHONPATH (so a test exercises this checkout, not an older
    install), the runtime directory is the test's private one and the configuration is the
    repository's ``config/``.
    """
    env = dict(os.environ)
    src = [os.path.join(ROOT, 'src', 'm4k_rt'), os.path.join(ROOT, 'src', 'm4k_drivers')]
    env['PYTHONPATH'] = os.pathsep.join(
        src + [x for x in env.get('PYTHONPATH', '').split(os.pathsep) if x])
    env['M4K_RUNTIME_DIR'] = runtime_dir
    env['M4K_CONFIG_DIR'] = os.path.join(ROOT, 'config')
    return env
