"""A robot's camera bringup: a USB camera through the usb_cam driver, calibrated from its spec sheet.

    sudo apt install ros-jazzy-usb-cam
    ros2 launch zeroshot_calib_ros usb_cam_bringup.launch.py video_device:=/dev/video0 \\
        width:=1920 height:=1080 hfov:=118 vfov:=69

Two nodes in the namespace `camera` (namespace:=...):

- usb_cam (executable usb_cam_node_exe) publishes camera/image_raw. Its own camera_info (without
  a calibration file: all zeros) is remapped to camera/driver/camera_info, and its
  set_camera_info to camera/driver/set_camera_info, so that neither meets ours.
- zeroshot_calib publishes camera/camera_info with the header of every camera/image_raw frame,
  camera/image_rect (rectify:=true, the default) and offers camera/set_camera_info
  (cameracalibrator). image_proc and VSLAM stacks subscribe to camera/image_raw and
  camera/camera_info as they would for any calibrated camera.

Give your camera's size (what the driver captures) and at least one spec-sheet FOV; a FOV left at
0 is not given. With none, zeroshot_calib exits with one line naming hfov, vfov and dfov.
For v4l2_camera instead of usb_cam: package v4l2_camera, executable v4l2_camera_node, parameters
video_device, image_size [width, height], pixel_format, camera_frame_id, and the same remappings.
`ros2 launch zeroshot_calib_ros usb_cam_bringup.launch.py --show-args` lists the arguments.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    arguments = [
        ('namespace', 'camera', 'namespace of both nodes, their topics and services'),
        ('video_device', '/dev/video0', 'the camera device usb_cam opens'),
        ('width', '1920', 'image width (px): what usb_cam captures and what the spec sheet describes'),
        ('height', '1080', 'image height (px): what usb_cam captures and what the spec sheet describes'),
        ('hfov', '0', 'spec-sheet horizontal field of view (deg); 0 = not given'),
        ('vfov', '0', 'spec-sheet vertical field of view (deg); 0 = not given'),
        ('dfov', '0', 'spec-sheet diagonal field of view (deg); 0 = not given'),
        ('pixel_format', 'mjpeg2rgb', "usb_cam's pixel_format (`ros2 run usb_cam usb_cam_node_exe` lists them)"),
        ('framerate', '30.0', 'frames per second usb_cam asks the camera for (a decimal: usb_cam wants a double)'),
        ('frame_id', 'camera_optical_frame', 'frame of the images and of the CameraInfo'),
        ('distortion_model', 'equidistant', 'CameraInfo model: equidistant (fisheye) or plumb_bob (narrow lenses)'),
        ('rectify', 'true', 'publish camera/image_rect (true/false)'),
    ]
    config = {name: LaunchConfiguration(name) for name, _, _ in arguments}
    return LaunchDescription([
        *[DeclareLaunchArgument(name, default_value=default, description=description)
          for name, default, description in arguments],
        Node(
            package='usb_cam',
            executable='usb_cam_node_exe',
            name='usb_cam',
            namespace=config['namespace'],
            parameters=[{'video_device': config['video_device'], 'image_width': config['width'],
                         'image_height': config['height'], 'pixel_format': config['pixel_format'],
                         'framerate': config['framerate'], 'frame_id': config['frame_id']}],
            # the driver's uncalibrated camera_info and its service, out of our way
            remappings=[('camera_info', 'driver/camera_info'), ('set_camera_info', 'driver/set_camera_info')],
            output='screen',
        ),
        Node(
            package='zeroshot_calib_ros',
            executable='node',
            name='zeroshot_calib',
            namespace=config['namespace'],
            parameters=[{'width': config['width'], 'height': config['height'], 'hfov': config['hfov'],
                         'vfov': config['vfov'], 'dfov': config['dfov'], 'frame_id': config['frame_id'],
                         'distortion_model': config['distortion_model'], 'rectify': config['rectify']}],
            output='screen',
        ),
    ])
