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


# What ros2cli's ros2run (Jazzy, 0.36) says, and tools/bin/ros2 with it: exit 1, the message
# on stderr's last line -- "No executable found" does not name the executable.
def test_ros2_run_says_no_executable_found_for_a_missing_executable():
    out = subprocess.run(['ros2', 'run', 'm4k_rt', 'no_such_exe'], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 1, out
    assert out.stderr.strip().splitlines()[-1] == 'No executable found', out.stderr


def test_ros2_run_says_which_package_is_missing():
    out = subprocess.run(['ros2', 'run', 'm4k_no_such_pkg', 'x'], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 1, out
    assert out.stderr.strip().splitlines()[-1] == "Package 'm4k_no_such_pkg' not found", \
        out.stderr


def test_ros2_pkg_prefix_of_a_missing_package_fails():
    out = subprocess.run(['ros2', 'pkg', 'prefix', 'm4k_no_such_pkg'], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 1, out
    assert out.stderr.strip().splitlines()[-1] == 'Package not found', out.stderr


def test_ros2_pkg_prefix_points_at_the_install_space():
    out = subprocess.run(['ros2', 'pkg', 'prefix', 'm4k_rt'], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0
    assert os.path.isdir(os.path.join(out.stdout.strip(), 'lib', 'm4k_rt'))
