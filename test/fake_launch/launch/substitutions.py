"""Stand-in for ``launch.substitutions``: LaunchConfiguration."""


class LaunchConfiguration:
    """The value of a launch argument, known once the context is."""

    def __init__(self, variable_name, *, default=None):
        self.variable_name = variable_name
        self.default = default

    def perform(self, context):
        """Return the argument's value in ``context`` (its ``launch_configurations``)."""
        return context.launch_configurations[self.variable_name]
