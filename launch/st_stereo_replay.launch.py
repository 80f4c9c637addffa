"""
Replay a bag through the rectifier, matcher and people on the bag's clock: ``bag_play --clock``.

``ros2 launch st_stereo st_stereo_replay.launch.py bag:=/path/to/bag [rate:=0.5]``: the
recorded raw pair (and ``pair_info``) are republished with their recorded stamps, ``/clock``
follows them and the nodes run with ``use_sim_time`` (so latencies, timers and TF lookups are
on the bag's time); the rig's static transforms as in ``st_stereo.launch.py``.
"""

from launch_ros.actions import Node
from st_stereo import launch_support

REPLAY_ARGUMENTS = [
    ('bag', '', 'the rosbag2 directory to replay (required)'),
    ('bag_namespace', '', 'the namespace of the image pair to replay from a bag of several '
     'rigs, e.g. /rig2/stereo (empty: the bag must hold one)'),
    ('rate', '1.0', 'replay speed, times the recorded pace'),
    ('use_sim_time', 'true', 'publish /clock from the bag and run the nodes on it'),
    ('start_delay', '3.0', 'seconds bag_play waits before the first message (for the nodes '
     'started with it to subscribe)'),
]


def bag_calibrations(value):
    """Return the calibration for the TF: the URL arguments', else the bag's camera_info."""
    from st_stereo.core.calibration.files import load_calibration
    from st_stereo.package_data import resolve_url
    from st_stereo.bag_streams import recorded_calibrations
    if value('left_camera_info_url') and value('right_camera_info_url'):
        return [load_calibration(resolve_url(value(f'{side}_camera_info_url')))
                for side in ('left', 'right')]
    return list(recorded_calibrations(value('bag'), value('bag_namespace')))


def launch_setup(value):
    """Build the player and the nodes from the performed launch arguments (``value(name)``)."""
    from st_stereo.nodes.bags import RAW_PAIR_TOPICS
    from st_stereo.bag_streams import bag_pair_namespace
    if not value('bag'):
        raise ValueError('launch argument bag: the rosbag2 directory to replay is required')
    use_sim_time = launch_support.flag(value('use_sim_time'), 'use_sim_time')
    play = [value('bag'), '--rate', str(launch_support.number(value('rate'), 'rate')),
            '--delay', str(launch_support.number(value('start_delay'), 'start_delay'))] + \
        (['--clock'] if use_sim_time else [])
    # The bag's raw pair into this launch's namespace (a bag recorded under another one).
    recorded = bag_pair_namespace(value('bag'), value('bag_namespace'))    # '/stereo/'
    target = '/' + value('namespace').strip('/')
    remappings = [(f'{recorded}{topic}', f'{target}/{topic}') for topic in RAW_PAIR_TOPICS] \
        if recorded != f'{target}/' else []
    return [Node(package='st_stereo', executable='bag_play', name='bag_play', arguments=play,
                 remappings=remappings, output='screen')] + \
        launch_support.stereo_nodes(value, bag_calibrations)


def generate_launch_description():
    """Declare the arguments; the nodes are made once they are known."""
    return launch_support.launch_description(REPLAY_ARGUMENTS, launch_setup)
