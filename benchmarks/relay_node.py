#!/usr/bin/env python3
"""Pass-through relay: image_raw -> image_rect, unchanged: the floor a rectifying node cannot beat.

Same process layout and QoS as the zeroshot_calib node with a best-effort camera (KEEP_LAST 5,
best effort, volatile, on both topics), same executor (rclpy.spin, single-threaded).

    --mode raw   (default) takes the serialised message and republishes those bytes: no
                 deserialisation at all, the cheapest a Python node can forward a frame.
    --mode msg   takes a sensor_msgs/Image (deserialised into Python) and publishes it again,
                 what a naive Python relay does.

Run with the benchmark environment (benchmarks/bench_common.py ros_env), e.g.

    .venv/bin/python benchmarks/relay_node.py --mode raw
"""
import argparse
import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.BEST_EFFORT,
                 durability=DurabilityPolicy.VOLATILE)


class Relay(Node):
    def __init__(self, mode: str, in_topic: str, out_topic: str):
        super().__init__('image_relay')
        self.count = 0
        self._pub = self.create_publisher(Image, out_topic, QOS)
        self.create_subscription(Image, in_topic, self._on_image, QOS, raw=(mode == 'raw'))

    def _on_image(self, msg):
        self._pub.publish(msg)
        self.count += 1


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--mode', choices=['raw', 'msg'], default='raw')
    p.add_argument('--in-topic', default='image_raw')
    p.add_argument('--out-topic', default='image_rect')
    args, ros_args = p.parse_known_args(argv)
    rclpy.init(args=[sys.argv[0], *ros_args])
    node = Relay(args.mode, args.in_topic, args.out_topic)
    print('RELAY READY', flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
