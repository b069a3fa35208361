"""Package m4k_rt (ament_python): the RT core, the robot's RT tasks, the ROS 2 bridge, bringup."""

from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'm4k_rt'
here = os.path.dirname(os.path.abspath(__file__))
# The workspace-level config/ is the single source of defaults; install it with the package.
config_files = sorted(
    os.path.relpath(p, here) for p in glob(os.path.join(here, '..', '..', 'config', '*.yaml')))
launch_files = sorted(os.path.relpath(p, here) for p in glob(os.path.join(here, 'launch', '*.py')))

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', config_files),
        ('share/' + package_name + '/launch', launch_files),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=False,
    maintainer='m4k maintainers',
    maintainer_email='maintainers@m4k-robotics.org',
    description='m4k real-time core, RT control tasks and ROS 2 bridge',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'rt_core = m4k_rt.rt_core:main',
            'rt_stat = m4k_rt.tools.rt_stat:main',
            'bridge = m4k_rt.bridge.node:main',
            'bringup = m4k_rt.tools.bringup:main',
            'echo_peer = m4k_rt.tasks.echo:main',
            'record = m4k_rt.bag.record:main',
        ],
    },
)
