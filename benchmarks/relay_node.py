#!/usr/bin/env python3
"""Pass-through relay: image_raw -> image_rect, unchanged: the floor a rectifying node cannot beat.

Same process layout and QoS as the zeroshot_calib node with a best-effort camera (KEEP_LAST 5,
best effort, volatile, on both topics), same executor as the node (by default rclpy's
SingleThreadedExecutor; see --executor).

    --mode raw   (default) takes the serialised message and republishes those bytes: no
                 deserialisation at all, the cheapest a Python node can forward a frame.
    --mode msg   takes a sensor_msgs/Image (deserialised into Python) and publishes it again,
                 what a naive Python relay does.
    --mode remap what the node must do per frame and nothing more: the raw relay that first
                 publishes the node's CameraInfo (a serialized template, the frame's stamp
                 patched in) on camera_info, then remaps the pixels viewed in the received bytes
                 with ``Rectifier.rectify`` on the node's maps (built at start for
                 ``--width``/``--height`` and the benchmark lens) into the node's reused
                 serialized image_rect (``SerializedImage``), and publishes it as bytes; the node's QoS (image_raw
                 depth 10, camera_info transient local). No checks, lookups, parameters or
                 diagnostics: the floor of a node like this one in a stream, where the remap
                 starts cold between frames (a back-to-back remap never does).

``--executor single|events``: rclpy's SingleThreadedExecutor (default, as ``rclpy.spin``) or its
EventsExecutor, spun as the node spins it (zeroshot_calib_ros/ros/executors.py).

Run with the benchmark environment (benchmarks/bench_common.py ros_env), e.g.

    .venv/bin/python benchmarks/relay_node.py --mode raw
"""
import argparse
import os
import sys

# as the node sets them, before OpenCV loads (zeroshot_calib_ros/ros/node.py says why)
for _name in ('OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER', 'OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN'):
    os.environ.setdefault(_name, '0')

import rclpy  # noqa: E402
from rclpy.executors import ExternalShutdownException  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.BEST_EFFORT,
                 durability=DurabilityPolicy.VOLATILE)
# --mode remap: the node's QoS with a best-effort camera (zeroshot_calib_ros/ros/node.py)
IN_QOS_REMAP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT,
                          durability=DurabilityPolicy.VOLATILE)
INFO_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Relay(Node):
    def __init__(self, mode: str, in_topic: str, out_topic: str, rectifier=None, calibration=None):
        super().__init__('image_relay')
        self.count = 0
        self._rectifier = rectifier
        self._rect = None  # SerializedImage: the node's reused serialized image_rect (--mode remap)
        self._info = None  # (frame_id, serialized CameraInfo template)
        self._calibration = calibration
        self._pub = self.create_publisher(Image, out_topic, QOS)
        if rectifier is None:
            self.create_subscription(Image, in_topic, self._on_image, QOS, raw=(mode == 'raw'))
            return
        from zeroshot_calib_ros.core.ros_formats.cdr_image import SerializedImage
        self._rect = SerializedImage()
        self._info_pub = self.create_publisher(CameraInfo, 'camera_info', INFO_QOS)
        self.create_subscription(Image, in_topic, self._on_image_remapped, IN_QOS_REMAP, raw=True)

    def _on_image(self, msg):
        self._pub.publish(msg)
        self.count += 1

    def _on_image_remapped(self, raw: bytes):
        from zeroshot_calib_ros.core.ros_formats.cdr_image import parse_image, patch_stamp, pixel_bytes
        from zeroshot_calib_ros.core.streaming.image_frames import image_array
        from zeroshot_calib_ros.ros.messages import serialized_camera_info
        from zeroshot_calib_ros.ros.node import publish_serialized

        header = parse_image(raw)  # a few microseconds; the same frame layout throughout a run
        if self._info is None or self._info[0] != header.frame_id:
            self._info = (header.frame_id, serialized_camera_info(self._calibration, header.frame_id))
        patch_stamp(self._info[1], header.sec, header.nanosec)
        publish_serialized(self._info_pub, self._info[1])
        image = image_array(pixel_bytes(raw, header), header.width, header.height, header.step, header.encoding)
        out = self._rect.prepare(header.sec, header.nanosec, header.frame_id, header.encoding, image.shape, image.dtype)
        self._rectifier.rectify(image, out=out)
        publish_serialized(self._pub, self._rect.buffer)
        self.count += 1


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--mode', choices=['raw', 'msg', 'remap'], default='raw')
    p.add_argument('--in-topic', default='image_raw')
    p.add_argument('--out-topic', default='image_rect')
    p.add_argument('--width', type=int, default=1920, help='frame width of --mode remap')
    p.add_argument('--height', type=int, default=1080, help='frame height of --mode remap')
    p.add_argument('--executor', choices=['single', 'events'], default='single',
                   help='rclpy executor: SingleThreadedExecutor (default) or EventsExecutor')
    args, ros_args = p.parse_known_args(argv)
    from bench_common import frames_in_heap, node_calibration
    frames_in_heap()  # first, as the node's main() does
    calibration = rectifier = None
    if args.mode == 'remap':  # the node's calibration and maps, before any frame comes (as the node has them)
        calibration, rectifier = node_calibration(args.width, args.height).for_size(args.width, args.height)
    from zeroshot_calib_ros.ros.executors import create_executor, spin
    rclpy.init(args=[sys.argv[0], *ros_args])
    executor, name, _ = create_executor(args.executor)
    node = Relay(args.mode, args.in_topic, args.out_topic, rectifier, calibration)
    executor.add_node(node)
    print(f'RELAY READY ({name})', flush=True)
    try:
        spin(executor, name)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
