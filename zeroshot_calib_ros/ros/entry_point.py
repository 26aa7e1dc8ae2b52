"""The node's executable (``ros2 run zeroshot_calib_ros node``): imports the node only inside
``main``, so that Ctrl-C while its libraries load (numpy, OpenCV, rclpy: a second or so) ends
the process quietly too, as it does at any later moment."""
from __future__ import annotations

import os
import signal


def _interrupted_while_loading(signum, frame):
    # Ctrl-C while numpy, OpenCV or rclpy load: a KeyboardInterrupt raised inside their C
    # extensions' imports comes out as an ImportError with a traceback (numpy: "PyCapsule_Import
    # could not import module datetime"), so no except clause can tell it apart. Nothing has
    # started yet (no ROS context, no file, no output): leave at once.
    os._exit(0)


def main(args=None) -> int:
    previous = signal.signal(signal.SIGINT, _interrupted_while_loading)
    try:
        from .node import main as node_main
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        return node_main(args)
    except KeyboardInterrupt:
        return 0
