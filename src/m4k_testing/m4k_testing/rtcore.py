"""Start rt_core from a test, on a package's source tree, with a quick configuration."""

from __future__ import annotations

import os
from typing import Any, Mapping

__all__ = ['fast_overlay', 'rt_core_env', 'start_rt_core', 'write_overlay']


def rt_core_env(src: str, extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """Return this process's environment with ``src`` first on PYTHONPATH, plus ``extra``."""
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join([os.path.abspath(src)] + [
        p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
    env.update(extra or {})
    return env


def write_overlay(tmp_path: Any, doc: Mapping[str, Any]) -> str:
    """Write ``doc`` as ``overlay.yaml`` under ``tmp_path``; return its path."""
    import yaml
    p = tmp_path / 'overlay.yaml'
    p.write_text(yaml.safe_dump(dict(doc)))
    return str(p)


def fast_overlay(tmp_path: Any, **runtime: Any) -> str:
    """Return an overlay for a small, quick rt_core: no memory locking, monitor every 0.3 s."""
    return write_overlay(tmp_path, {
        'runtime': {'mlockall': False, 'cpu_dma_latency': False, 'start_delay_ms': 10,
                    **runtime},
        'tasks': {'monitor': {'period_ms': 300}}})


def start_rt_core(procs: Any, src: str, args: list[str],
                  env: Mapping[str, str] | None = None) -> Any:
    """Start ``python -m m4k_rt.rt_core args`` through the ``procs`` fixture."""
    return procs.start(['python', '-m', 'm4k_rt.rt_core', *args], env=rt_core_env(src, env))
