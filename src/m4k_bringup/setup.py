"""Package m4k_bringup (ament_python): system integration -- bringup, the launch file, config/."""

from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'm4k_bringup'
here = os.path.dirname(os.path.abspath(__file__))
# The workspace-level config/ is the single source of defaults; this package is its one install.
config_files = sorted(
    os.path.relpath(p, here) for p in glob(os.path.join(here, '..', '..', 'config', '*.yaml')))
layout_files = sorted(  # the Foxglove layout of the live view (ros2 run m4k_bridge foxglove)
    os.path.relpath(p, here) for p in glob(os.path.join(here, '..', '..', 'config', 'foxglove',
                                                        '*.json')))
# Recipes for the stack around the base (docs/nav2.md): config/<tool>/.
config_dir = os.path.join(here, '..', '..', 'config')
recipes = [('share/{}/config/{}'.format(package_name, d),
            sorted(os.path.relpath(p, here) for p in glob(os.path.join(config_dir, d, '*'))))
           for d in ('rviz', 'nav2', 'slam_toolbox', 'twist_mux', 'robot_localization',
                     'diagnostics')]
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
        ('share/' + package_name + '/config/foxglove', layout_files),
        ('share/' + package_name + '/launch', launch_files),
        *recipes,
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=False,
    maintainer='m4k maintainers',
    maintainer_email='maintainers@m4k-robotics.org',
    description='m4k system integration: bringup, the launch file, the configuration and its docs',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bringup = m4k_bringup.bringup:main',
            'config_doc = m4k_bringup.configdoc:main',
            'recipes = m4k_bringup.recipes:main',
        ],
    },
)
