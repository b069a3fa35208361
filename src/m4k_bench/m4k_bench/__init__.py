"""m4k evidence: bench, core_bench, xddp_bench, demo, soak, fuzz, the plain-ROS baseline, DWA."""

__version__ = '0.1.0'
