"""What ROS carries, without ROS (layer 4): calibration files, CameraInfo, images, maps.

``calibration_file`` (camera_info_manager / camera_calibration_parsers files and URLs),
``camera_info_model`` (image_geometry's model of a CameraInfo, in Python), ``rectify``
(rectified camera P and the rectification maps), ``image_frames`` (sensor_msgs/Image
encodings and checks, the calibration in force and its maps), ``node_parameters`` and
``map_builder`` (the node's parameter table and map thread), ``cdr_image`` (serialized Image and
CameraInfo without rclpy), ``heap`` (the allocator settings of a process that streams frames)
and ``online_refinement`` (the node's refinement worker). Imports the layers below; never
rclpy or a message package: the ROS node (``zeroshot_calib_ros.ros``) converts messages.
"""
