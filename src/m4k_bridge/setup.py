"""Package m4k_bridge (ament_python): the ROS 2 face of m4k -- the bridge node and the recorder."""

from setuptools import find_packages, setup

package_name = 'm4k_bridge'

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
    description='m4k ROS 2 bridge (the only rclpy code of the stack) and MCAP recorder',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bridge = m4k_bridge.node:main',
            'record = m4k_bridge.bag.record:main',
            'foxglove = m4k_bridge.foxglove.node:main',
            'doctor = m4k_bridge.doctor:main',
        ],
    },
)
