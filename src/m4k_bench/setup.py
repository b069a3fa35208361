"""Package m4k_bench (ament_python): everything that produces evidence about m4k.

The benchmarks (bench, core_bench, xddp_bench), the demo with its DWA planner and evaluation,
the soak, the fuzzer and the plain-ROS baseline node they compare against. The robot stack
(m4k_rt, m4k_drivers) does not depend on this package.
"""

from setuptools import find_packages, setup

package_name = 'm4k_bench'

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
    description='m4k evidence: benchmarks, demo and planner, soak, fuzz, plain-ROS baseline',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bench = m4k_bench.bench:main',
            'core_bench = m4k_bench.core_bench:main',
            'xddp_bench = m4k_bench.xddp_bench:main',
            'demo = m4k_bench.demo:main',
            'liveview = m4k_bench.liveview:main',
            'flightrec_bench = m4k_bench.flightrec_bench:main',
            'soak = m4k_bench.soak:main',
            'fuzz = m4k_bench.fuzz:main',
            'baseline = m4k_bench.baseline:main',
            'loop_ab = m4k_bench.loop_ab:main',
            'scenarios = m4k_bench.scenarios:main',
            'reaction = m4k_bench.reaction:main',
            'bench_combine = m4k_bench.benchlib.combine:main',
            'rt_stat = m4k_bench.rt_stat:main',
            'echo_peer = m4k_bench.echo_peer:main',
        ],
    },
)
