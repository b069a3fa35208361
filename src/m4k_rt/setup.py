"""Package m4k_rt (ament_python): the RT core and the robot's RT tasks -- no ROS at run time."""

from setuptools import find_packages, setup

package_name = 'm4k_rt'

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
    description='m4k real-time core and RT control tasks (ROS-free)',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'rt_core = m4k_rt.rt_core:main',
        ],
    },
)
