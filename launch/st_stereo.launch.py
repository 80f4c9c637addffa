"""Launch the rig on a real ROS 2 Jazzy install: driver, rectifier and matcher in `stereo`."""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory('st_stereo')
    parameters = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='stereo',
                              description='namespace of every topic and node'),
        DeclareLaunchArgument('params_file',
                              default_value=os.path.join(share, 'config', 'st_stereo.yaml'),
                              description='ROS 2 parameter file of the three nodes'),
        Node(package='st_stereo', executable='lepton_driver', name='lepton_driver',
             namespace=namespace, parameters=[parameters], output='screen'),
        Node(package='st_stereo', executable='rectifier', name='rectifier',
             namespace=namespace, parameters=[parameters], output='screen'),
        Node(package='st_stereo', executable='matcher', name='matcher',
             namespace=namespace, parameters=[parameters], output='screen'),
    ])
