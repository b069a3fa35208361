"""m4k_bridge.interfaces: the one loader of ROS interface classes by type name."""

import pytest

from m4k_bridge.interfaces import interface_class


def test_full_and_short_names_load_the_generated_classes():
    from geometry_msgs.msg import Twist
    from std_srvs.srv import Trigger

    from m4k_msgs.msg import RtStatus
    assert interface_class('geometry_msgs/msg/Twist') is Twist
    assert interface_class('geometry_msgs/Twist') is Twist
    assert interface_class('m4k_msgs/msg/RtStatus') is RtStatus
    assert interface_class('std_srvs/srv/Trigger') is Trigger
    assert interface_class('std_srvs/Trigger', 'srv') is Trigger


@pytest.mark.parametrize('name', ['Twist', 'geometry_msgs//Twist', 'a/b/c/d', ''])
def test_a_malformed_name_is_a_value_error(name):
    with pytest.raises(ValueError, match='not an interface type name'):
        interface_class(name)


def test_an_unknown_type_raises_what_the_import_raises():
    with pytest.raises(ModuleNotFoundError):
        interface_class('no_such_pkg/msg/X')
    with pytest.raises(AttributeError):
        interface_class('geometry_msgs/msg/NoSuchType')
