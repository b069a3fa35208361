"""Package m4k_drivers (ament_python): NRT device handlers, simulated world, driver host."""

from setuptools import find_packages, setup

package_name = 'm4k_drivers'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=False,
    maintainer='m4k maintainers',
    maintainer_email='maintainers@m4k-robotics.org',
    description='m4k NRT device handlers (real and simulated) and the driver host',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'driver_host = m4k_drivers.host:main',
            'sim_robot = m4k_drivers.sim_robot:main',
            'sim_truth = m4k_drivers.sim_robot:truth_main',
            'calibrate = m4k_drivers.calibrate.cli:main',
            'sonar_echo_width = m4k_drivers.sonar.echowidth:main',
            'bringup_check = m4k_drivers.bringup.cli:main',
        ],
    },
)
