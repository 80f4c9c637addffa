"""Stand-in for ``launch.actions``: DeclareLaunchArgument, OpaqueFunction."""


class DeclareLaunchArgument:
    """A launch argument with its default and description."""

    def __init__(self, name, *, default_value=None, description=''):
        self.name = name
        self.default_value = default_value
        self.description = description


class OpaqueFunction:
    """A function called with the launch context, returning actions."""

    def __init__(self, *, function, args=None, kwargs=None):
        self.function = function
        self.args = args or []
        self.kwargs = kwargs or {}
