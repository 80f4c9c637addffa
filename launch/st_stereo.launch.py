"""
Launch the rig on a ROS 2 Jazzy install: driver, rectifier, matcher, people and the static TF.

``ros2 launch st_stereo st_stereo.launch.py [source:=spi] [namespace:=stereo] ...``; every
argument: ``ros2 launch st_stereo st_stereo.launch.py --show-args``. Empty arguments leave the
parameter file's value.
"""

from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from st_stereo import launch_support

RIG_ARGUMENTS = [
    ('source', '', 'driver source: sim, capture, spi, purethermal or bag (empty: as in the '
     'parameter file)'),
    ('bag', '', 'source bag: the rosbag2 directory'),
    ('bag_namespace', '', 'source bag: the namespace of the image pair to replay, e.g. '
     '/rig2/stereo (empty: as in the parameter file)'),
    ('left_device', '', "spi: the left camera's spidev device"),
    ('right_device', '', "spi: the right camera's spidev device"),
    ('left_i2c_bus', '', "spi: the left camera's I2C bus number"),
    ('right_i2c_bus', '', "spi: the right camera's I2C bus number"),
    ('use_sim_time', 'false', "use /clock as the nodes' clock"),
    ('respawn', 'true', 'restart the driver when it exits (it does after give_up_after)'),
    ('respawn_delay', '2.0', 'seconds before a respawn'),
]


def launch_setup(value):
    """Build the nodes from the performed launch arguments (``value(name)``)."""
    use_sim_time = launch_support.flag(value('use_sim_time'), 'use_sim_time')
    # Only what a launch argument sets overrides the parameter file; strings stay strings
    # (launch_ros would read "1" as an integer).
    driver = {'use_sim_time': use_sim_time}
    for name, parameter in (('source', 'source'), ('bag', 'bag'),
                            ('bag_namespace', 'bag_namespace'),
                            ('left_device', 'left_device'), ('right_device', 'right_device'),
                            ('left_camera_info_url', 'left.camera_info_url'),
                            ('right_camera_info_url', 'right.camera_info_url')):
        if value(name):
            driver[parameter] = ParameterValue(value(name), value_type=str)
    for name in ('left_i2c_bus', 'right_i2c_bus'):
        if value(name):
            driver[name] = launch_support.integer(value(name), name)
    if value('left_camera_info_url') or value('right_camera_info_url'):
        # Calibration URLs given: they, not a replayed bag's own camera_info (source bag).
        driver['bag_camera_info'] = False
    return [Node(package='st_stereo', executable='lepton_driver', name='lepton_driver',
                 namespace=value('namespace'), parameters=[value('params_file'), driver],
                 ros_arguments=['--log-level', value('log_level')],
                 respawn=launch_support.flag(value('respawn'), 'respawn'),
                 respawn_delay=launch_support.number(value('respawn_delay'), 'respawn_delay'),
                 output='screen')] + launch_support.stereo_nodes(value)


def generate_launch_description():
    """Declare the arguments; the nodes are made once they are known."""
    return launch_support.launch_description(RIG_ARGUMENTS, launch_setup)
