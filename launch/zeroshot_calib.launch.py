"""Launch the zero-shot calibration node for one camera.

    ros2 launch zeroshot_calib_ros zeroshot_calib.launch.py \
        params_file:=/path/to/camera.yaml namespace:=front image:=/front/image_raw rectify:=true

Defaults to the package's Hero9 W1 params file.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory('zeroshot_calib_ros'), 'config',
                                  'hero9_w1.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='ROS parameters file of the camera (/**/zeroshot_calib: ros__parameters:)'),
        DeclareLaunchArgument('namespace', default_value='camera', description='namespace of the topics'),
        DeclareLaunchArgument('image', default_value='image_raw',
                              description='raw image topic to pair CameraInfo with / rectify'),
        DeclareLaunchArgument('rectify', default_value='false', description='publish image_rect'),
        Node(
            package='zeroshot_calib_ros',
            executable='node',
            name='zeroshot_calib',
            namespace=LaunchConfiguration('namespace'),
            parameters=[LaunchConfiguration('params_file'), {'rectify': LaunchConfiguration('rectify')}],
            remappings=[('image_raw', LaunchConfiguration('image'))],
            output='screen',
        ),
    ])
