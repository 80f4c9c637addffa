"""Stand-in for ``launch_ros.parameter_descriptions``: ParameterValue."""


class ParameterValue:
    """A parameter value with its type fixed (launch_ros would YAML-parse a bare string)."""

    def __init__(self, value, *, value_type=None):
        self.value = value
        self.value_type = value_type
