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


# What ros2cli's ros2run (Jazzy, 0.32) says, and tools/bin/ros2 with it (both checked:
# docs/results/ros-verify.md): exit 1, the message on stderr's last line -- "No executable
# found" does not name the executable.
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


def test_ros2_run_reports_a_failing_executable_and_returns_its_status():
    # ros2run waits for the executable and says on stdout how it ended; the arguments after
    # the executable's name are the executable's, even one spelled like ros2run's --prefix.
    out = subprocess.run(['ros2', 'run', 'm4k_bringup', 'config_doc', '--prefix', 'x'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out
    assert out.stdout.strip().splitlines()[-1] == '[ros2run]: Process exited with failure 2'
    assert 'config_doc: error: unrecognized arguments: --prefix x' in out.stderr, out.stderr


def test_ros2_run_prefix_goes_in_front_of_the_executable():
    prefix = subprocess.run(['ros2', 'pkg', 'prefix', 'm4k_rt'], capture_output=True,
                            text=True, timeout=60).stdout.strip()
    out = subprocess.run(['ros2', 'run', '--prefix', 'echo with', 'm4k_rt', 'rt_core', '-h'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f'with {prefix}/lib/m4k_rt/rt_core -h'


def test_ros2_pkg_prefix_share_is_the_share_directory():
    out = subprocess.run(['ros2', 'pkg', 'prefix', '--share', 'm4k_bringup'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert os.path.isfile(os.path.join(out.stdout.strip(), 'launch', 'm4k.launch.py'))


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
