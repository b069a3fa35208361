"""fleetcheck's judgements on hand-built graphs (pure: no ROS graph needed)."""

from m4k_bridge.fleetcheck import (
    duplicate_edges,
    frame_parameter_problems,
    TF_TYPE,
    TfSample,
    tree_problems,
)
from m4k_bridge.graphcheck import Endpoint

TREE = [TfSample('/r1/tf', False, 'odom', 'base_footprint', 1.0),
        TfSample('/r1/tf_static', True, 'base_footprint', 'base_link', 1.0),
        TfSample('/r2/tf', False, 'odom', 'base_footprint', 1.0)]


def test_a_costmap_without_its_own_listener_is_judged_on_its_robot_s_tree():
    # Nav2's costmap node reads tf through a listener node of its own, in the robot's ns
    params = {'/r1/local_costmap/local_costmap': {'robot_base_frame': 'r1/base_link',
                                                  'global_frame': 'odom'},
              '/r1/m4k_bridge': {'odom_frame': 'odom', 'frame_prefix': 'r1/'}}
    lines = frame_parameter_problems([], params, TREE)
    assert len(lines) == 1, lines
    assert lines[0].startswith("/r1/local_costmap/local_costmap robot_base_frame: "
                               "'r1/base_link' is not a frame of the tree on /r1/tf")


def test_each_robot_s_tree_is_judged_on_its_own_topics():
    # two robots' identical unprefixed frames are no split and no second parent
    assert tree_problems(TREE, [], now=1.5, stale_s=1.0) == []
    split = TREE + [TfSample('/r1/tf', False, 'map', 'odom_other', 1.0)]
    assert 'the TF tree on /r1/tf is split into 2 trees with roots map, odom' in \
        tree_problems(split, [], now=1.5, stale_s=1.0)[0]


def test_an_edge_two_nodes_say_they_broadcast_is_named_only_in_the_same_tree():
    eps = [Endpoint('/r1/m4k_bridge', 'pub', '/r1/tf', TF_TYPE),
           Endpoint('/r1/ekf_filter_node', 'pub', '/r1/tf', TF_TYPE),
           Endpoint('/r2/ekf_filter_node', 'pub', '/r2/tf', TF_TYPE)]
    ekf = {'publish_tf': True, 'world_frame': 'odom', 'base_link_frame': 'base_footprint'}
    params = {'/r1/m4k_bridge': {'publish_tf': True, 'odom_frame': 'odom',
                                 'footprint_frame': 'base_footprint'},
              '/r1/ekf_filter_node': ekf, '/r2/ekf_filter_node': ekf}
    lines = duplicate_edges(eps, params)
    assert len(lines) == 1 and lines[0].startswith(
        'odom -> base_footprint on /r1/tf is broadcast by 2 nodes'), lines
    params['/r1/m4k_bridge']['publish_tf'] = False
    assert duplicate_edges(eps, params) == []
