"""Package m4k_testing (ament_python): the test machinery every m4k test suite shares."""

from setuptools import find_packages, setup

package_name = 'm4k_testing'

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
    description='m4k test machinery: shared pytest fixtures, markers, skip policy (tests only)',
    license='Apache-2.0',
)
