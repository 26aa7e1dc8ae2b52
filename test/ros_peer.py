"""A ROS participant in the test process, talking to the node under test in its own process.

The node runs as the installed executable (what ``ros2 run zeroshot_calib_ros node`` starts),
in a fresh ROS domain per test, with DDS discovery restricted to this machine.
"""
import itertools
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import rclpy
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

REPO = Path(__file__).resolve().parents[1]
NODE_EXECUTABLE = REPO / 'install' / 'zeroshot_calib_ros' / 'lib' / 'zeroshot_calib_ros' / 'node'
DDS_PROFILE = REPO / 'config' / 'fastdds_shm.xml'
_domains = itertools.count(1 + os.getpid() % 60)


def ros_environment(domain_id: int) -> dict:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               RMW_IMPLEMENTATION='rmw_fastrtps_cpp', FASTDDS_DEFAULT_PROFILES_FILE=str(DDS_PROFILE),
               FASTRTPS_DEFAULT_PROFILES_FILE=str(DDS_PROFILE), PYTHONUNBUFFERED='1')
    return env


def qos(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE, depth=10):
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
                      durability=durability)


LATCHED = qos(durability=DurabilityPolicy.TRANSIENT_LOCAL)


class NodeProcess:
    """The node under test in its own process; stdout/stderr collected to a file."""

    def __init__(self, args, domain_id, tmp_path, name='node', prefix=()):
        if not NODE_EXECUTABLE.exists():
            pytest.fail(f'{NODE_EXECUTABLE} is missing: build first (make build)')
        self.log_path = tmp_path / f'{name}.log'
        self._log = open(self.log_path, 'w')
        env = ros_environment(domain_id)
        # camera_info_manager's default URL is under $ROS_HOME: never the user's ~/.ros
        env['ROS_HOME'] = str(tmp_path / 'ros_home')
        # prefix: a command the node runs under (e.g. prlimit --as=... --)
        self.process = subprocess.Popen([*prefix, str(NODE_EXECUTABLE), *args], env=env,
                                        stdout=self._log, stderr=subprocess.STDOUT, cwd=str(REPO))

    @property
    def log(self) -> str:
        return self.log_path.read_text()

    def alive(self) -> bool:
        return self.process.poll() is None

    def wait(self, timeout=20.0) -> int:
        return self.process.wait(timeout)

    def stop(self):
        if self.alive():
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._log.close()


class Peer:
    """rclpy in the test process, in its own context and domain."""

    def __init__(self, domain_id: int):
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node('test_peer', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate, timeout=20.0, what='condition'):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return
            self.executor.spin_once(timeout_sec=0.05)
        raise AssertionError(f'timed out after {timeout:.0f} s waiting for {what}')

    def spin_for(self, seconds):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)

    def collect(self, msg_type, topic, qos_profile):
        received = []
        self.node.create_subscription(msg_type, topic, received.append, qos_profile)
        return received

    def image_publisher(self, qos_profile, topic='image_raw'):
        """A publisher on ``topic`` once the node subscribes to it, after the node had time to
        match its QoS to this publisher's (it checks once a second)."""
        pub = self.node.create_publisher(Image, topic, qos_profile)
        self.spin_until(lambda: pub.get_subscription_count() > 0, what=f'the node subscribing to {topic}')
        self.spin_for(1.5)
        return pub

    def call(self, srv_type, name, request, timeout=20.0):
        client = self.node.create_client(srv_type, name)
        self.spin_until(lambda: client.service_is_ready(), timeout, f'service {name}')
        future = client.call_async(request)
        self.spin_until(future.done, timeout, f'response of {name}')
        return future.result()

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@pytest.fixture
def domain_id():
    # ZEROSHOT_TEST_DOMAIN_OFFSET (0 or 100): two test runs on one machine in domains apart
    return next(_domains) % 100 + 1 + int(os.environ.get('ZEROSHOT_TEST_DOMAIN_OFFSET', '0'))


@pytest.fixture
def peer(domain_id):
    p = Peer(domain_id)
    yield p
    p.close()


@pytest.fixture
def start_node(domain_id, tmp_path):
    started = []

    def start(*args, name='node', prefix=()):
        process = NodeProcess(list(args), domain_id, tmp_path, name=f'{name}{len(started)}', prefix=prefix)
        started.append(process)
        return process

    yield start
    for process in started:
        process.stop()


def image_msg(array, encoding, stamp_ns, frame_id='cam'):
    msg = Image()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.header.frame_id = frame_id
    msg.height, msg.width = array.shape[:2]
    msg.encoding = encoding
    msg.step = array.strides[0]
    msg.data = array.tobytes()
    return msg


def diagnostics_value(messages, key):
    for msg in reversed(messages):
        for status in msg.status:
            for kv in status.values:
                if kv.key == key:
                    return kv.value
    return None


def parameter_msg(name, value):
    """rcl_interfaces/Parameter of any Python value (None: NOT_SET; lists: arrays)."""
    p = Parameter(name=name)
    if value is None:
        p.value = ParameterValue(type=ParameterType.PARAMETER_NOT_SET)
    elif isinstance(value, bool):
        p.value = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
    elif isinstance(value, int):
        p.value = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value)
    elif isinstance(value, float):
        p.value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
    elif isinstance(value, str):
        p.value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
    elif all(isinstance(v, bool) for v in value):
        p.value = ParameterValue(type=ParameterType.PARAMETER_BOOL_ARRAY, bool_array_value=list(value))
    elif all(isinstance(v, int) for v in value):
        p.value = ParameterValue(type=ParameterType.PARAMETER_INTEGER_ARRAY, integer_array_value=list(value))
    elif all(isinstance(v, float) for v in value):
        p.value = ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=list(value))
    else:
        p.value = ParameterValue(type=ParameterType.PARAMETER_STRING_ARRAY, string_array_value=list(value))
    return p
