"""The node's executable (``ros2 run zeroshot_calib_ros node``): imports the node only inside
``main``, so that Ctrl-C while its libraries load (numpy, OpenCV, rclpy: a second or so) ends
the process quietly too, as it does at any later moment."""
from __future__ import annotations


def main(args=None) -> int:
    try:
        from .node import main as node_main
        return node_main(args)
    except KeyboardInterrupt:
        return 0
