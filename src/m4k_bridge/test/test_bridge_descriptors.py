"""The bridge's ParameterDescriptors come from the schema Fields (in-process rclpy node)."""

import pytest
import rclpy
from rclpy.parameter import Parameter

from m4k_bridge import params
from m4k_bridge.node import BridgeNode
from m4k_rt import config

pytestmark = [pytest.mark.allow_leaks('fds'),  # in-process DDS transports outlive the node
              pytest.mark.e2e]           # ROS nodes: the end-to-end tier


@pytest.fixture
def bridge(m4k_runtime_dir):
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = None
    try:
        node = BridgeNode(context=context, parameter_overrides=[
            Parameter('runtime_dir', value=m4k_runtime_dir)])
        yield node
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_descriptors_carry_the_schema_range_unit_read_only_and_source(bridge):
    by_name = {d.name: d for d in bridge.describe_parameters(
        ['cmd_vel_timeout', 'ports.cmd', 'stats_window', 'odom_pose_covariance_diagonal'])}
    timeout = by_name['cmd_vel_timeout']
    field = params.spec('cmd_vel_timeout')
    rng = timeout.floating_point_range[0]
    assert (rng.from_value, rng.to_value) == (field.lo, field.hi)
    assert timeout.description.startswith(field.description)
    assert 'Unit: s.' in timeout.description and 'control.cmd_vel_timeout' in timeout.description
    assert not timeout.read_only
    port = by_name['ports.cmd']
    assert port.read_only and "the label 'cmd' of the ports section" in port.description
    cov = by_name['odom_pose_covariance_diagonal']
    assert '6 elements' in cov.additional_constraints and 'within [0.0' in \
        cov.additional_constraints


def test_derived_parameters_start_at_the_layered_configurations_values(bridge):
    doc = config.load_layered()
    assert bridge.get_parameter('cmd_vel_timeout').value == doc['control']['cmd_vel_timeout']
    assert bridge.get_parameter('max_linear_velocity').value == \
        doc['control']['linear']['max_velocity']
    assert bridge.get_parameter('sonar_frame').value == doc['robot']['sensors']['sonar']['frame']


def test_a_changed_derived_value_is_refused_out_of_the_schema_range(bridge):
    # rclpy itself enforces the descriptor's range, before the node's own check.
    result = bridge.set_parameters([Parameter('cmd_vel_timeout', value=90.0)])[0]
    assert not result.successful and 'out of range' in result.reason
    assert 'Max: 60.0' in result.reason
