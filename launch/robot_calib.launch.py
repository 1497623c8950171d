# Copyright 2026 robot_calib contributors
# SPDX-License-Identifier: Apache-2.0
"""
Launch robot_calib nodes with the package's parameter file (needs a full ROS 2 install).

Every node by default, or those named in ``nodes`` (comma-separated executables)::

    ros2 launch robot_calib robot_calib.launch.py
    ros2 launch robot_calib robot_calib.launch.py nodes:=tilt_detection namespace:=robot1 \
        params_file:=/path/to/my_robot.yaml use_sim_time:=true
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from robot_calib import methods


def _nodes(context):
    wanted = LaunchConfiguration('nodes').perform(context)
    names = [n.strip() for n in wanted.split(',') if n.strip()] if wanted else methods.names()
    unknown = sorted(set(names) - set(methods.names()))
    if unknown:
        raise RuntimeError(f'unknown node(s) {unknown}; known: {", ".join(methods.names())}')
    params = LaunchConfiguration('params_file').perform(context)
    sim_time = LaunchConfiguration('use_sim_time').perform(context).lower() == 'true'
    return [Node(package='robot_calib', executable=name, name=name,
                 namespace=LaunchConfiguration('namespace'), output='screen',
                 parameters=[params, {'use_sim_time': sim_time}])
            for name in names]


def generate_launch_description():
    """Declare the arguments and the nodes."""
    default_params = os.path.join(get_package_share_directory('robot_calib'), 'config',
                                  'robot_calib.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('nodes', default_value='',
                              description='comma-separated executables (empty: every node)'),
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='ROS 2 parameter YAML'),
        DeclareLaunchArgument('namespace', default_value='', description='node namespace'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='use /clock (true when replaying a bag)'),
        OpaqueFunction(function=_nodes),
    ])
