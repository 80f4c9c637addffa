"""
ROS parameters of the ST matcher, declared from STConfig's own field metadata.

Every field becomes a parameter with a ParameterDescriptor (description, integer or floating
point range, the allowed strings in the description), and live changes are validated by
building the new STConfig: an invalid value is rejected with the config's own message.
"""

import math

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)

from st_stereo.core.config import describe_fields, STConfig


def parameter_descriptor(name, kind, meta):
    """Build the ParameterDescriptor of one STConfig field."""
    description = meta['description']
    if meta['choices']:
        description += f' (one of: {", ".join(meta["choices"])})'
    descriptor = ParameterDescriptor(name=name, description=description)
    if meta['low'] is not None and kind is int:
        step = 2 if meta['odd'] else 1
        low = meta['low'] if not meta['odd'] or meta['low'] % 2 else meta['low'] + 1
        descriptor.integer_range = [IntegerRange(from_value=int(low),
                                                 to_value=int(meta['high']), step=step)]
    elif meta['low'] is not None and kind is float:
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=float(meta['low']), to_value=float(meta['high']), step=0.0)]
    return descriptor


def declare_st_parameters(node, prefix=''):
    """Declare every ST parameter on a node; returns the STConfig they describe."""
    for name, kind, default, meta in describe_fields():
        node.declare_parameter(prefix + name, default,
                               parameter_descriptor(prefix + name, kind, meta))
    return config_from_node(node, prefix)


def config_from_node(node, prefix=''):
    """Build the STConfig of a node's current parameter values."""
    values = {name: node.get_parameter(prefix + name).value
              for name, _, _, _ in describe_fields()}
    return STConfig(**values)


def validate_changes(current, parameters, prefix=''):
    """
    Check a batch of parameter changes against STConfig.

    Returns
    -------
    (SetParametersResult, STConfig or None)
        The new config when every change is valid.

    """
    names = {name for name, _, _, _ in describe_fields()}
    changes = {}
    for parameter in parameters:
        if not parameter.name.startswith(prefix):
            continue
        name = parameter.name[len(prefix):]
        if name in names:
            value = parameter.value
            if isinstance(value, float) and not math.isfinite(value):
                return SetParametersResult(successful=False,
                                           reason=f'{name}: expected a finite number'), None
            changes[name] = value
    if not changes:
        return SetParametersResult(successful=True), None
    try:
        config = STConfig(**{**current.to_dict(), **changes})
    except ValueError as error:
        return SetParametersResult(successful=False, reason=str(error)), None
    return SetParametersResult(successful=True), config
