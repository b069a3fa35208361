"""`ros2 run <pkg> <exe>` resolves m4k's executables (the ros2cli shim or a real ros2)."""

import os
import shutil
import subprocess

import pytest


@pytest.mark.parametrize('pkg,exe', [
    ('m4k_rt', 'rt_core'), ('m4k_drivers', 'driver_host'), ('m4k_bench', 'bench'),
    ('m4k_bench', 'baseline'), ('m4k_bringup', 'bringup'), ('m4k_bridge', 'record'),
    ('m4k_bringup', 'config_doc'),
])
def test_ros2_run_starts_the_installed_executable(pkg, exe):
    ros2 = shutil.which('ros2')
    assert ros2, 'tools/env.sh puts a ros2 on PATH'
    out = subprocess.run([ros2, 'run', pkg, exe, '--help'], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert 'usage:' in out.stdout.lower()


def test_ros2_run_names_a_missing_executable():
    out = subprocess.run(['ros2', 'run', 'm4k_rt', 'no_such_exe'], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode != 0
    assert 'no_such_exe' in out.stderr


def test_ros2_pkg_prefix_points_at_the_install_space():
    out = subprocess.run(['ros2', 'pkg', 'prefix', 'm4k_rt'], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0
    assert os.path.isdir(os.path.join(out.stdout.strip(), 'lib', 'm4k_rt'))
