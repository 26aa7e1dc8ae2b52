"""Launch the zero-shot calibration node for one camera.

    ros2 launch zeroshot_calib_ros zeroshot_calib.launch.py \
        params_file:=/path/to/camera.yaml namespace:=front image_topic:=/front/image_raw rectify:=true

From a bringup: IncludeLaunchDescription(PythonLaunchDescriptionSource(PathJoinSubstitution(
[FindPackageShare('zeroshot_calib_ros'), 'launch', 'zeroshot_calib.launch.py'])), launch_arguments=...).
`ros2 launch zeroshot_calib_ros zeroshot_calib.launch.py --show-args` lists the arguments.
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
        DeclareLaunchArgument(
            'params_file', default_value=default_params,
            description='ROS parameters file of your camera (keyed /**/<node_name>: ros__parameters:, or /**:). '
                        'The default is the GoPro Hero9 wide 1920x1080 (16:9) spec: frames of that aspect ratio '
                        'get its CameraInfo (scaled to their size); frames of another aspect ratio (640x480 is '
                        '4:3) get none, and the node says so (a WARN naming the parameters to set: width, height '
                        'and hfov/vfov/dfov or preset; /diagnostics ERROR). Give your camera\'s file'),
        DeclareLaunchArgument('namespace', default_value='camera',
                              description='namespace of the node and of its relative topics and service'),
        DeclareLaunchArgument(
            'node_name', default_value='zeroshot_calib',
            description='node name (the shipped params files are keyed /**/zeroshot_calib: with another name, '
                        'key your file /**/<node_name> or /**)'),
        DeclareLaunchArgument('image', default_value='image_raw',
                              description='older name of image_topic (used when image_topic is not given)'),
        DeclareLaunchArgument('image_topic', default_value=LaunchConfiguration('image'),
                              description='raw image topic to pair CameraInfo with and to rectify (image_raw '
                                          'remapped)'),
        DeclareLaunchArgument(
            'camera_info_topic', default_value='camera_info',
            description='topic of the published CameraInfo (camera_info remapped): set it when the camera '
                        'driver publishes its own camera_info in the same namespace, e.g. zeroshot/camera_info'),
        DeclareLaunchArgument('image_rect_topic', default_value='image_rect',
                              description='rectified image topic (image_rect remapped; with rectify:=true)'),
        DeclareLaunchArgument(
            'set_camera_info_service', default_value='set_camera_info',
            description='SetCameraInfo service (set_camera_info remapped): set it when the camera driver offers '
                        'its own set_camera_info in the same namespace'),
        DeclareLaunchArgument('rectify', default_value='false', description='publish image_rect (true/false)'),
        DeclareLaunchArgument('log_level', default_value='info',
                              description='log level of the node: debug, info, warn, error or fatal'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='stamp with /clock (simulation, bag replay) instead of the system '
                                          'clock (true/false)'),
        Node(
            package='zeroshot_calib_ros',
            executable='node',
            name=LaunchConfiguration('node_name'),
            namespace=LaunchConfiguration('namespace'),
            parameters=[LaunchConfiguration('params_file'), {'rectify': LaunchConfiguration('rectify'),
                                                            'use_sim_time': LaunchConfiguration('use_sim_time')}],
            remappings=[('image_raw', LaunchConfiguration('image_topic')),
                        ('camera_info', LaunchConfiguration('camera_info_topic')),
                        ('image_rect', LaunchConfiguration('image_rect_topic')),
                        ('set_camera_info', LaunchConfiguration('set_camera_info_service'))],
            ros_arguments=['--log-level', LaunchConfiguration('log_level')],
            output='screen',
        ),
    ])
