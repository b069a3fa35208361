"""The built workspace is laid out the way ROS 2 tools expect it."""

import configparser
import os
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET

from ament_index_python.packages import get_package_prefix, get_package_share_directory
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PYTHON_PACKAGES = ('m4k_rt', 'm4k_drivers', 'm4k_bridge', 'm4k_bringup', 'm4k_bench')
TEST_PACKAGES = ('m4k_testing',)   # the tests' fixtures: built and installed, no scripts
CONFIG_PACKAGES = ('m4k_bringup',)  # the one install of config/; the others find it there


def _console_scripts(pkg: str) -> list[str]:
    """Read the console script names from the package's setup.py entry points."""
    with open(os.path.join(ROOT, 'src', pkg, 'setup.py')) as f:
        text = f.read()
    return re.findall(r"'(\w+) = [\w.]+:\w+'", text)


@pytest.mark.parametrize('pkg', PYTHON_PACKAGES)
def test_every_console_script_is_where_ros2_run_looks(pkg):
    scripts = _console_scripts(pkg)
    assert scripts, f'{pkg} declares no console scripts'
    prefix = get_package_prefix(pkg)  # the ament index, as `ros2 run` resolves it
    for exe in scripts:
        path = os.path.join(prefix, 'lib', pkg, exe)
        assert os.path.isfile(path), f'ros2 run {pkg} {exe}: {path} missing'
        assert os.access(path, os.X_OK), f'{path} is not executable'


@pytest.mark.parametrize('pkg', PYTHON_PACKAGES + TEST_PACKAGES)
def test_setup_cfg_installs_scripts_into_lib_pkg(pkg):
    cfg = configparser.ConfigParser()
    cfg.read(os.path.join(ROOT, 'src', pkg, 'setup.cfg'))
    assert cfg['install']['install_scripts'] == f'$base/lib/{pkg}'
    assert cfg['develop']['script_dir'] == f'$base/lib/{pkg}'


@pytest.mark.parametrize('pkg', PYTHON_PACKAGES + TEST_PACKAGES + ('m4k_msgs',))
def test_package_xml_has_valid_maintainer_email(pkg):
    # An invalid email makes colcon treat the package as plain python (no ament index).
    root = ET.parse(os.path.join(ROOT, 'src', pkg, 'package.xml')).getroot()
    emails = [m.get('email') for m in root.findall('maintainer')]
    assert emails and all(re.fullmatch(r'[\w.+-]+@[\w-]+(\.[\w-]+)*\.[a-z]{2,}', e)
                          for e in emails), emails


@pytest.mark.parametrize('pkg', TEST_PACKAGES)
def test_the_test_package_is_built_and_the_tests_import_the_installed_one(pkg):
    # colcon builds it like the others (the ament index has it) and the conftest.py files
    # import it from install/, as colcon test does -- not from a source path.
    module = __import__(pkg)
    prefix = get_package_prefix(pkg)
    assert os.path.realpath(module.__file__).startswith(os.path.realpath(prefix) + os.sep)


@pytest.mark.parametrize('pkg', CONFIG_PACKAGES)
def test_default_config_is_installed_to_share(pkg):
    share = get_package_share_directory(pkg)
    installed = set(os.listdir(os.path.join(share, 'config')))
    expected = {f for f in os.listdir(os.path.join(ROOT, 'config')) if f.endswith('.yaml')}
    assert expected and expected <= installed


def test_second_setup_run_does_nothing():
    # The stamp from the first run makes the second a no-op: no output, no reinstall.
    out = subprocess.run([os.path.join(ROOT, 'tools', 'setup.sh')], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout == '' and out.stderr == ''


@pytest.mark.parametrize('missing,package', [('cmake', 'cmake'), ('g++', 'g++')])
def test_setup_names_the_package_of_a_missing_prerequisite(tmp_path, missing, package):
    # A PATH with everything the setup script needs except one prerequisite.
    bin_dir = tmp_path / 'bin'
    bin_dir.mkdir()
    for tool in ('bash', 'dirname', 'cmake', 'gcc', 'g++', 'make', 'python3.11', 'python3.12',
                 'sha256sum', 'cut', 'cat', 'grep', 'sed'):
        found = shutil.which(tool)
        if found and tool != missing:
            os.symlink(found, bin_dir / tool)
    out = subprocess.run(['bash', os.path.join(ROOT, 'tools', 'setup.sh')], capture_output=True,
                         text=True, timeout=60, env={'PATH': str(bin_dir), 'HOME': str(tmp_path),
                                                     'M4K_USE_WHEELS': '1'})
    assert out.returncode == 1
    assert out.stderr.strip() == (
        f"m4k setup: error: '{missing}' not found -- install it: sudo apt-get install {package}")
