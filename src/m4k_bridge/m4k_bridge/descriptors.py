"""ROS parameter descriptors from schema Fields, shared by the bridge and the live view."""

from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

from m4k_bridge.params import PARAM_TYPES
from m4k_rt.schema import Field

__all__ = ['TYPES', 'descriptor']

# Schema type -> ROS ParameterType, derived from the bridge's one table of parameter types.
TYPES = {t.schema: getattr(ParameterType, t.descriptor) for t in PARAM_TYPES}


def descriptor(f: Field) -> ParameterDescriptor:
    """Return the ROS descriptor of a schema Field: type, range, read-only, unit, source."""
    text = f.description
    if f.unit:
        text += ' Unit: {}.'.format(f.unit)
    if f.derived_from and 'Derived' not in text:
        text += ' Derived from {} of the layered configuration.'.format(f.derived_from)
    if f.type == 'any':     # a bool or a keyword (enable_stamped_cmd_vel: auto)
        return ParameterDescriptor(name=f.name, description=text, read_only=f.read_only,
                                   dynamic_typing=True)
    d = ParameterDescriptor(name=f.name, type=TYPES[f.type], description=text,
                            read_only=f.read_only)
    if f.lo is not None and f.hi is not None:
        if f.type == 'float':
            d.floating_point_range = [FloatingPointRange(from_value=float(f.lo),
                                                         to_value=float(f.hi), step=0.0)]
        elif f.type == 'int':
            d.integer_range = [IntegerRange(from_value=int(f.lo), to_value=int(f.hi), step=1)]
        else:
            d.additional_constraints = 'every element within [{}, {}]'.format(f.lo, f.hi)
    if f.length is not None:
        d.additional_constraints = ' '.join(filter(None, (
            '{} elements;'.format(f.length), d.additional_constraints)))
    return d
