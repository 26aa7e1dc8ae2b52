"""The ROS 2 front end (top layer): the node and what only it needs of rclpy.

Parameters, topics and services; every computation is in ``zeroshot_calib_ros.core``.
"""
import os

# One BLAS thread for the node's process, read when numpy's OpenBLAS loads (rclpy's messages load
# numpy after this): its computations are tiny systems a second thread never speeds up, and beside
# a busy camera driver OpenBLAS's waiting threads slow them down (the `zeroshot-calib` command does
# the same: benchmarks/results/blas_threads.md). A user's setting wins.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
