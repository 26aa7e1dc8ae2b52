"""Print the CameraInfo a running node publishes, as `ros2 topic echo` prints it, with rclpy
alone (no system ROS, no ros2cli): what `make echo` runs.

    make run                                   # the node, in one terminal
    make echo                                  # /camera_info, once, in another
    make echo TOPIC=/front/camera_info ECHO_ARGS='--count 3 --timeout 20'

It listens both ways the node may publish: reliable with transient local durability (the last
CameraInfo is kept for late joiners, what the node offers while no camera streams) and best
effort (a camera that streams best effort). Exit status 0 after --count messages, 1 when none
came within --timeout seconds (one line on stderr saying so), 2 for bad arguments.
"""
from __future__ import annotations

import argparse
import os
import sys
import time


def camera_info_yaml(msg) -> str:
    """One sensor_msgs/CameraInfo in the layout of `ros2 topic echo` (YAML, one array item a
    line), ending with its `---` separator."""
    lines = ['header:', '  stamp:', f'    sec: {msg.header.stamp.sec}', f'    nanosec: {msg.header.stamp.nanosec}',
             f'  frame_id: {msg.header.frame_id}', f'height: {msg.height}', f'width: {msg.width}',
             f'distortion_model: {msg.distortion_model}']
    for name in ('d', 'k', 'r', 'p'):
        values = list(getattr(msg, name))
        lines.append(f'{name}:' if values else f'{name}: []')
        lines += [f'- {float(v)!r}' for v in values]
    lines += [f'binning_x: {msg.binning_x}', f'binning_y: {msg.binning_y}', 'roi:',
              f'  x_offset: {msg.roi.x_offset}', f'  y_offset: {msg.roi.y_offset}', f'  height: {msg.roi.height}',
              f'  width: {msg.roi.width}', f'  do_rectify: {str(msg.roi.do_rectify).lower()}', '---']
    return '\n'.join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='make echo', description='print the sensor_msgs/CameraInfo published on TOPIC (ros2 topic echo)')
    parser.add_argument('topic', nargs='?', default='/camera_info',
                        help='CameraInfo topic (default /camera_info, where `make run` publishes it)')
    parser.add_argument('--count', type=int, default=1, help='messages to print, then exit (default 1)')
    parser.add_argument('--timeout', type=float, default=10.0,
                        help='seconds to wait for each message before giving up (default 10)')
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.count < 1:
        print(f'make echo: error: count = {args.count} is invalid: allowed: 1 or more', file=sys.stderr)
        return 2
    if not args.timeout > 0:
        print(f'make echo: error: timeout = {args.timeout} is invalid: allowed: seconds, greater than 0',
              file=sys.stderr)
        return 2
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo

    rclpy.init(args=['--ros-args', '--disable-rosout-logs'])
    node = rclpy.create_node('zeroshot_calib_echo')
    received, seen = [], set()

    def take(msg):
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec, tuple(msg.k), tuple(msg.d), tuple(msg.p))
        if key not in seen:  # the same message through both subscriptions counts once
            seen.add(key)
            received.append(msg)
    latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    streamed = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.BEST_EFFORT,
                          durability=DurabilityPolicy.VOLATILE)
    node.create_subscription(CameraInfo, args.topic, take, latched)
    node.create_subscription(CameraInfo, args.topic, take, streamed)
    printed = 0
    try:
        while printed < args.count:
            deadline = time.monotonic() + args.timeout
            while len(received) <= printed and time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.05)
            if len(received) <= printed:
                domain = os.environ.get('ROS_DOMAIN_ID', '0')
                print(f'make echo: no CameraInfo on {node.resolve_topic_name(args.topic)} within {args.timeout:g} s '
                      f'(ROS_DOMAIN_ID {domain}): is the node running (make run), and in that namespace?',
                      file=sys.stderr)
                return 1
            print(camera_info_yaml(received[printed]), flush=True)
            printed += 1
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
