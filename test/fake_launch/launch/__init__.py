"""Stand-in for ROS 2 ``launch`` (see ../README.md)."""


class LaunchDescription:
    """The entities of a launch file, in order."""

    def __init__(self, entities=None):
        self.entities = list(entities or [])
