#!/usr/bin/env python3
"""Start-up to the first CameraInfo in another process, with DDS discovery separated out.

    .venv/bin/python benchmarks/first_camera_info.py [--trials 12] [--width 1920 --height 1080] [--rectify]

Each trial runs in its own ROS_DOMAIN_ID (LOCALHOST discovery, the environment of the caller
otherwise: run it with the Makefile's ROS environment, e.g. the shared-memory profile). A
subscriber (reliable, transient local, as a late joiner would be) is up first; then the
installed node is started (rectify off, or on with ``--rectify``) and three times are recorded from its process start:
when the node logged its calibration (the node is ready and has published its first
CameraInfo), when the subscriber matched the node's publisher (DDS discovery), and when the
first CameraInfo arrived. The difference between "ready" and "matched" is discovery, which
the node does not control.
"""
from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

TOP = Path(__file__).resolve().parents[1]
NODE = TOP / 'install' / 'zeroshot_calib_ros' / 'lib' / 'zeroshot_calib_ros' / 'node'


def trial(width: int, height: int, rectify: bool = False) -> dict:
    """One measurement in this process (its own domain, set by the caller)."""
    import rclpy
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo
    rclpy.init()
    node = rclpy.create_node('first_camera_info_probe')
    got, matched = [], []
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(CameraInfo, 'camera_info', lambda m: got.append(time.time()), qos,
                             event_callbacks=SubscriptionEventCallbacks(matched=lambda e: matched.append(time.time())))
    for _ in range(50):
        rclpy.spin_once(node, timeout_sec=0.01)
    t0 = time.time()
    child = subprocess.Popen([sys.executable, str(NODE), '--ros-args', '-p', f'width:={width}', '-p', f'height:={height}',
                              '-p', 'hfov:=118', '-p', 'vfov:=69', '-p', f'rectify:={str(rectify).lower()}'], stderr=subprocess.PIPE, text=True)
    while not got and time.time() - t0 < 20:
        rclpy.spin_once(node, timeout_sec=0.01)
    time.sleep(0.5)  # the node logs its calibration just after publishing it: let the line out
    child.terminate()
    err = child.communicate(timeout=20)[1]
    logged = re.search(r'\[INFO\] \[(\d+\.\d+)\]', err)
    nan = float('nan')
    return {'ready_s': float(logged.group(1)) - t0 if logged else nan,
            'matched_s': matched[0] - t0 if matched else nan, 'first_camera_info_s': got[0] - t0 if got else nan}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--trials', type=int, default=12)
    parser.add_argument('--width', type=int, default=1920)
    parser.add_argument('--height', type=int, default=1080)
    parser.add_argument('--rectify', action='store_true', help='start the node with rectify:=true')
    parser.add_argument('--trial', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.trial:
        print(repr(trial(args.width, args.height, args.rectify)))
        return 0
    rows = []
    for i in range(args.trials):
        env = dict(os.environ, ROS_DOMAIN_ID=str(150 + i), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        out = subprocess.run([sys.executable, __file__, '--trial', '--width', str(args.width), '--height', str(args.height)]
                             + ['--rectify'] * args.rectify,
                             env=env, capture_output=True, text=True, timeout=60).stdout.strip().splitlines()
        rows.append(eval(out[-1], {'nan': float('nan')}))  # our own repr of a dict of floats
        print(f"trial {i + 1}: node ready {rows[-1]['ready_s']:.3f} s, matched {rows[-1]['matched_s']:.3f} s, "
              f"first CameraInfo {rows[-1]['first_camera_info_s']:.3f} s", flush=True)
    first = [r['first_camera_info_s'] for r in rows]
    ready = [r['ready_s'] for r in rows]
    limit = 0.9 if args.rectify else 0.6
    print(f"median: node ready {statistics.median(ready):.3f} s, first CameraInfo {statistics.median(first):.3f} s; "
          f"first CameraInfo <= {limit} s in {sum(f <= limit for f in first)} of {len(first)} trials")
    return 0


if __name__ == '__main__':
    sys.exit(main())
