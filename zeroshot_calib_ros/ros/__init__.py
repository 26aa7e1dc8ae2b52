"""The ROS 2 front end (top layer): the node and what only it needs of rclpy.

Parameters, topics and services; every computation is in ``zeroshot_calib_ros.core``.
"""
