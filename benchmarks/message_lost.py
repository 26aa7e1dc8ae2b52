#!/usr/bin/env python3
"""Why `ros2 topic echo --once camera_info` sometimes prints "A message was lost!!!".

`ros2 topic echo` registers a message_lost event callback and prints that line when the
middleware reports lost samples. This joins the node's camera_info (no camera: 10 Hz CameraInfo
of its own, KEEP_LAST 5, reliable, transient local) RUNS times with a late-joining subscription
of the same QoS and a message_lost callback, as `ros2 topic echo` does, then does the same
against a plain rclpy publisher with the same QoS and rate, and prints how many joins saw lost
samples for each.

    .venv/bin/python benchmarks/message_lost.py --runs 20

A late joiner of a transient-local KEEP_LAST writer that keeps publishing is sent the writer's
history; a sample that leaves that history (replaced by a newer one) before the joiner has
received it is announced as a GAP, which Fast DDS counts as lost. That is the same for any
publisher of this QoS and rate (the plain rclpy publisher shows it as often as the node), and
never when the publisher is silent while the reader joins: no message of the live stream is lost.
"""
from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import time

from bench_common import NODE_EXECUTABLE, ros_env

PLAIN = '''
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, HistoryPolicy, ReliabilityPolicy, DurabilityPolicy
from sensor_msgs.msg import CameraInfo
rclpy.init()
node = Node('plain_camera_info')
qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
pub = node.create_publisher(CameraInfo, 'camera_info', qos)
import sys
count = [0]
def tick():
    if len(sys.argv) > 1 and count[0] >= int(sys.argv[1]):
        return  # silent after that many: the history no longer changes while a reader joins
    count[0] += 1
    msg = CameraInfo()
    msg.header.stamp = node.get_clock().now().to_msg()
    pub.publish(msg)
tick()
node.create_timer(0.1, tick)
rclpy.spin(node)
'''


def joins(domain: int, runs: int) -> list:
    import rclpy
    from rclpy.context import Context
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    lost_per_run = []
    for run in range(runs):
        context = Context()
        rclpy.init(context=context, domain_id=domain)
        node = Node(f'echo_{run}', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        lost = []
        callbacks = SubscriptionEventCallbacks(message_lost=lambda info: lost.append(info.total_count_change))
        node.create_subscription(CameraInfo, 'camera_info', lambda msg: None, qos, event_callbacks=callbacks)
        end = time.monotonic() + 1.5
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        lost_per_run.append(sum(lost))
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        time.sleep(random.uniform(0.0, 0.5))
    return lost_per_run


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=12)
    args = parser.parse_args()
    for label, command, domain in (
            ('node', [str(NODE_EXECUTABLE), '--ros-args', '-p', 'width:=1920', '-p', 'height:=1080',
                      '-p', 'hfov:=118', '-p', 'vfov:=69'], 171),
            ('plain rclpy publisher', [sys.executable, '-c', PLAIN], 172),
            ('plain rclpy publisher, silent after 10 messages', [sys.executable, '-c', PLAIN, '10'], 173)):
        env = ros_env(domain)
        env['ROS_HOME'] = os.path.join('/tmp', f'message_lost_{os.getpid()}')
        os.environ.update({k: env[k] for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'RMW_IMPLEMENTATION',
                                               'FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE')})
        process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            time.sleep(3.0)
            lost = joins(domain, args.runs)
        finally:
            process.terminate()
            process.wait(10)
        print(f'{label}: {sum(1 for n in lost if n)} of {len(lost)} late joins reported lost samples '
              f'(counts {[n for n in lost if n]})', flush=True)


if __name__ == '__main__':
    main()
