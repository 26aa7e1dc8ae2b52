"""A stand-in for usb_cam's driver (usb_cam_node_exe) where it is not installed, for the bringup test:
the same parameter names, and what it publishes and offers under the names usb_cam uses:
image_raw, camera_info on the fully qualified name image_transport's CameraPublisher gives it
(<namespace>/camera_info, uncalibrated: all zeros, as usb_cam without a calibration file), and
set_camera_info (camera_info_manager). Frames: mono8 of image_width x image_height, 10 Hz."""
import sys

import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo


class FakeUsbCam(Node):
    def __init__(self):
        super().__init__('usb_cam')
        for name, default in (('video_device', '/dev/video0'), ('image_width', 640), ('image_height', 480),
                              ('pixel_format', 'yuyv'), ('framerate', 30.0), ('frame_id', 'default_cam')):
            self.declare_parameter(name, default)
        self.width = self.get_parameter('image_width').value
        self.height = self.get_parameter('image_height').value
        self.frame_id = self.get_parameter('frame_id').value
        namespace = self.get_namespace().rstrip('/')
        self.image_pub = self.create_publisher(Image, 'image_raw', QoSProfile(depth=100))
        self.info_pub = self.create_publisher(CameraInfo, f'{namespace}/camera_info', QoSProfile(depth=100))
        self.create_service(SetCameraInfo, 'set_camera_info', lambda request, response: response)
        rng = np.random.default_rng(0)
        self.pixels = rng.integers(0, 256, (self.height, self.width), dtype=np.uint8).tobytes()
        self.create_timer(0.1, self.publish)

    def publish(self):
        image = Image(height=self.height, width=self.width, encoding='mono8', step=self.width, data=self.pixels)
        image.header.stamp = self.get_clock().now().to_msg()
        image.header.frame_id = self.frame_id
        info = CameraInfo(header=image.header, height=self.height, width=self.width)
        self.image_pub.publish(image)
        self.info_pub.publish(info)


def main():
    rclpy.init(args=sys.argv)
    node = FakeUsbCam()
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
