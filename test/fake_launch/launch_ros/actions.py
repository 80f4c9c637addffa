"""Stand-in for ``launch_ros.actions``: Node, recording its keyword arguments."""

NODE_KEYWORDS = ('package', 'executable', 'name', 'namespace', 'parameters', 'arguments',
                 'ros_arguments', 'remappings', 'respawn', 'respawn_delay', 'output')


class Node:
    """A ROS node to start: what launch_ros.actions.Node takes, kept as attributes."""

    def __init__(self, *, executable, package=None, **kwargs):
        unknown = set(kwargs) - set(NODE_KEYWORDS)
        if unknown:
            raise TypeError(f'launch_ros.actions.Node: unexpected keywords {sorted(unknown)}')
        self.package = package
        self.executable = executable
        for keyword in NODE_KEYWORDS[2:]:
            setattr(self, keyword, kwargs.get(keyword))
