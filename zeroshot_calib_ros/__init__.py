"""Zero-shot calibration of wide-angle and fisheye cameras for ROS 2 (J.-Y. Lee, CVPR 2021).

``zeroshot_calib_ros.core`` is the ROS-free library, ``zeroshot_calib_ros.cli`` the
``zeroshot-calib`` command and ``zeroshot_calib_ros.ros.node`` the ROS 2 node.
"""
__version__ = '0.1.0'
