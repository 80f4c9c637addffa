"""
ROS parameters of the ST matcher, declared from STConfig's own field metadata.

Every field becomes a parameter with a ParameterDescriptor (description, integer or floating
point range, the allowed strings in the description), and live changes are validated by
building the new STConfig: an invalid value is rejected with the config's own message.
"""

import math

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.exceptions import InvalidParameterTypeException

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


def declare_typed(node, name, default, descriptor):
    """
    Declare one parameter; a value of the wrong type is a ValueError saying what to write.

    rclpy's own exception does not say what is expected in a parameter file's terms.
    """
    try:
        node.declare_parameter(name, default, descriptor)
    except InvalidParameterTypeException as error:
        kind = type(default).__name__
        hint = ' (a number with a decimal point, e.g. 3.0 rather than 3)' \
            if kind == 'float' else ''
        raise ValueError(f'parameter {name}: expected a {kind}{hint}; rclpy: {error}') \
            from None


def declare_st_parameters(node, prefix=''):
    """Declare every ST parameter on a node; returns the STConfig they describe."""
    for name, kind, default, meta in describe_fields():
        declare_typed(node, prefix + name, default,
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


READ_ONLY_REASON = 'read once at start-up: set it in the parameter file or on the command line'


def node_parameter_descriptor(parameter):
    """Return the descriptor of a ``NodeParameter``: read-only unless a live change has effect."""
    descriptor = ParameterDescriptor(name=parameter.name, description=parameter.description,
                                     read_only=not parameter.live)
    if not parameter.live:
        descriptor.additional_constraints = READ_ONLY_REASON
    return descriptor


def declare_node_parameters(node, parameters, deprecated=None):
    """
    Declare a node's ``NodeParameter`` list (see ``st_stereo.nodes.node_parameters``).

    ``deprecated`` maps old names to new ones: an old name still given (a parameter file, the
    command line) becomes the new parameter's value unless the new name is given too, with a
    warning either way, so ``ros2 param get`` shows the value in use under the new name. A
    value of the wrong type is a ValueError naming the parameter and the type expected.
    """
    renamed = {new: old for old, new in (deprecated or {}).items()}
    for old, new in (deprecated or {}).items():
        node.declare_parameter(old, '', ParameterDescriptor(
            name=old, description=f'deprecated: use {new}', read_only=True))
    for parameter in parameters:
        default = parameter.default
        old = renamed.get(parameter.name)
        old_value = node.get_parameter(old).value if old else ''
        if old_value:
            default = old_value
        declare_typed(node, parameter.name, default, node_parameter_descriptor(parameter))
        if old_value:
            value = node.get_parameter(parameter.name).value
            if value != old_value:
                node.get_logger().warning(f'parameters {old} and {parameter.name} are both '
                                          f'set: using {parameter.name} ({old} is deprecated)')
            else:
                node.get_logger().warning(f'parameter {old} is deprecated: use '
                                          f'{parameter.name}')
