"""
What the launch files (``launch/*.launch.py``) share: their arguments and the static transforms.

Imports ``launch`` and ``launch_ros`` when called (a ROS 2 install has them; the package's own
code never needs them). The transforms' numbers come from ``st_stereo.core.rig_pose``.
"""

from st_stereo.core.calibration.files import load_calibration
from st_stereo.core.config import parse_bool
from st_stereo.core.rig_pose import load_rig_pose, POSE_FIELDS, rig_pose_from_mapping, \
    rig_static_transforms, static_transform_arguments
from st_stereo.nodes.node_parameters import driver_parameter
from st_stereo.package_data import resolve_url


def flag(text, name):
    """Return a launch argument's text as a bool; ValueError names the argument."""
    try:
        return parse_bool(text)
    except ValueError as error:
        raise ValueError(f'launch argument {name}: {error}') from None


def common_arguments(share):
    """Return the launch arguments both launch files declare (name, default, description)."""
    return [
        ('namespace', 'stereo', 'namespace of every node and topic of this rig'),
        ('params_file', f'{share}/config/st_stereo.yaml', 'ROS 2 parameter file of the nodes'),
        ('rig_pose_file', f'{share}/config/rig_pose.yaml',
         "the rig's pose in the room (world -> rig -> left optical frame)"),
        ('left_camera_info_url', '', "left calibration URL (empty: the parameter file's)"),
        ('right_camera_info_url', '', "right calibration URL (empty: the parameter file's)"),
        ('publish_tf', 'true', 'start tf2_ros static_transform_publisher for the rig'),
        ('log_level', 'info', 'log level of the st_stereo nodes'),
    ] + [(field, '', f'rig pose: {field} (empty: as in rig_pose_file)') for field in POSE_FIELDS]


def number(text, name):
    """Return a launch argument's text as a float; ValueError names the argument."""
    try:
        return float(text)
    except ValueError:
        raise ValueError(f'launch argument {name}: expected a number, got {text!r}') from None


def integer(text, name):
    """Return a launch argument's text as an int; ValueError names the argument."""
    try:
        return int(text)
    except ValueError:
        raise ValueError(f'launch argument {name}: expected an integer, got {text!r}') \
            from None


def rig_pose(value):
    """
    Return the RigPose of ``rig_pose_file`` with the non-empty pose launch arguments over it.

    The file must give ``height_m`` unless the ``height_m`` argument does.
    """
    pose = load_rig_pose(value('rig_pose_file'), () if value('height_m') else ('height_m',))
    fields = {field: getattr(pose, field) for field in POSE_FIELDS}
    for field in POSE_FIELDS:
        if value(field):
            fields[field] = value(field) if field.endswith('frame') else \
                number(value(field), field)
    return rig_pose_from_mapping(fields, 'launch arguments')


def calibration_urls(value):
    """
    Return the two camera_info URLs the driver will use.

    The launch arguments' (which the launch file also passes to the driver), else what the
    parameter file gives the driver in this namespace (as rcl resolves it, so the transforms
    and the driver agree).
    """
    return [value(f'{side}_camera_info_url') or
            driver_parameter(value('params_file'), f'{side}.camera_info_url', value('namespace'))
            for side in ('left', 'right')]


def driver_calibrations(value):
    """
    Return the two calibrations the driver will publish, for the transforms.

    The camera_info URLs' (``calibration_urls``), but for a driver replaying a bag
    (``source`` bag) with ``bag_camera_info`` (not when the launch gives URLs) whose bag has
    its own camera_info: that one, as the driver publishes it.
    """
    def driver(name):
        return value(name) or driver_parameter(value('params_file'), name, value('namespace'))
    urls_given = value('left_camera_info_url') or value('right_camera_info_url')
    if driver('source') == 'bag' and driver('bag') and not urls_given and \
            driver_parameter(value('params_file'), 'bag_camera_info', value('namespace')):
        from st_stereo.bag_streams import recorded_calibrations
        try:
            return list(recorded_calibrations(driver('bag'), driver('bag_namespace') or ''))
        except ValueError:          # no camera_info in the bag: the driver's URLs
            pass
    return [load_calibration(resolve_url(url)) for url in calibration_urls(value)]


def rig_transforms(value, calibrations):
    """Return the rig's three StaticTransforms (pose, calibrations, the driver's frame ids)."""
    frames = [driver_parameter(value('params_file'), f'{side}.frame_id', value('namespace'))
              for side in ('left', 'right')]
    return rig_static_transforms(rig_pose(value), *calibrations, *frames)


def static_transform_nodes(transforms, namespace, use_sim_time):
    """Return one tf2_ros static_transform_publisher node per transform."""
    from launch_ros.actions import Node
    return [Node(package='tf2_ros', executable='static_transform_publisher',
                 name=f'static_tf_{index}', namespace=namespace,
                 arguments=static_transform_arguments(transform),
                 parameters=[{'use_sim_time': use_sim_time}], output='log')
            for index, transform in enumerate(transforms)]


def stereo_nodes(value, calibrations_for_tf=None):
    """
    Return the rectifier, the matcher, the people node and (unless ``publish_tf`` is false) TF.

    The people node gets the rig pose (``rig_pose_file`` and the pose arguments over it) as
    its parameters, after the parameter file's: one pose for the transforms and the people.

    ``value(name)``: a launch argument's performed text. The transforms' calibration is the
    driver's (``driver_calibrations``) unless ``calibrations_for_tf(value)`` gives another.
    """
    from launch_ros.actions import Node
    namespace, params_file = value('namespace'), value('params_file')
    use_sim_time = flag(value('use_sim_time'), 'use_sim_time')
    nodes = [Node(package='st_stereo', executable=executable, name=executable,
                  namespace=namespace, parameters=[params_file, {'use_sim_time': use_sim_time}],
                  ros_arguments=['--log-level', value('log_level')], output='screen')
             for executable in ('rectifier', 'matcher')]
    pose = rig_pose(value)
    people = {'use_sim_time': use_sim_time, 'world_frame': pose.world_frame}
    people.update({field: float(getattr(pose, field)) for field in POSE_FIELDS[2:]})
    nodes.append(Node(package='st_stereo', executable='people', name='people',
                      namespace=namespace, parameters=[params_file, people],
                      ros_arguments=['--log-level', value('log_level')], output='screen'))
    if flag(value('publish_tf'), 'publish_tf'):
        calibrations = calibrations_for_tf(value) if calibrations_for_tf else \
            driver_calibrations(value)
        nodes += static_transform_nodes(rig_transforms(value, calibrations), namespace,
                                        use_sim_time)
    return nodes


def launch_description(arguments, setup):
    """
    Return a LaunchDescription declaring the common and ``arguments``; ``setup`` makes nodes.

    ``setup(value)`` gets a function returning a launch argument's performed text and returns
    the actions (an OpaqueFunction: the arguments are known only when the launch runs).
    """
    from ament_index_python.packages import get_package_share_directory
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction
    from launch.substitutions import LaunchConfiguration

    def perform(context):
        return setup(lambda name: LaunchConfiguration(name).perform(context))
    declared = common_arguments(get_package_share_directory('st_stereo')) + arguments
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=description)
         for name, default, description in declared] + [OpaqueFunction(function=perform)])
