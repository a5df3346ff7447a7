"""Launch the node press_twin with the package's parameters.

``ros2 launch mps_ros press_twin.launch.py [scene:=press-cycle] [params_file:=...]`` starts the
node press_twin (``mps node``) with the package's parameters YAML. Discovery stays on
this machine unless the environment says otherwise (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST is
set for the node when the variable is unset).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    config = os.path.join(get_package_share_directory("mps_ros"), "config", "press_twin.yaml")
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")}
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "scene", default_value="press-cycle", description="preset name or scene file"
            ),
            DeclareLaunchArgument(
                "params_file", default_value=config, description="the node's parameters (YAML)"
            ),
            Node(
                package="mps_ros",
                executable="mps",
                name="press_twin",
                arguments=["node", LaunchConfiguration("scene")],
                parameters=[LaunchConfiguration("params_file")],
                additional_env=env,
                output="screen",
                emulate_tty=True,
            ),
        ]
    )
