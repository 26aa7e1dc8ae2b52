"""The streaming pipeline the node drives, without ROS (layer 5): frames in, CameraInfo and
rectified images out.

``image_frames`` (sensor_msgs/Image encodings and checks, the calibration in force and its
maps), ``map_builder`` (the node's map thread), ``heap`` (the allocator settings of a process that
streams frames), ``online_refinement`` (the node's refinement worker) and ``node_parameters``
(the node's parameter table and ``Settings``); the node's collaborators: ``frame_path`` (a frame
-> its calibration, serialized CameraInfo and rectified image, or why it is skipped),
``map_requests`` (which maps are built when, and what a finished build means),
``calibration_cycle`` (which calibration is in force and what may replace it, the saves),
``refinement_control`` (the refiner's life cycle) and ``diagnostics`` (the /diagnostics status).
Imports ``core.ros_formats`` and the layers below; never rclpy or a message package: the ROS
node (``zeroshot_calib_ros.ros``) converts messages.
"""
