"""The formats ROS carries, without ROS (layer 4): calibration files, CameraInfo, images, maps.

``calibration_file`` (camera_info_manager / camera_calibration_parsers files and URLs),
``camera_info_model`` (image_geometry's model of a CameraInfo, in Python), ``rectify``
(rectified camera P and the rectification maps: what a CameraInfo means to image_proc) and
``cdr_image`` (serialized Image and CameraInfo without rclpy). Imports the layers below; never
``core.streaming``, rclpy or a message package: the ROS node (``zeroshot_calib_ros.ros``)
converts messages.
"""
