#!/usr/bin/env python3
"""Shared plumbing of the benchmarks: the ROS environment of every child process, children
bounded in time, and two helper roles run as their own processes:

* ``pub``: publishes one pre-serialised sensor_msgs/Image (best effort, as camera drivers do)
  on command (``RUN rate seconds`` on stdin), stamping each frame with the wall clock just
  before ``publish``; prints ``S <stamp_ns>`` per frame.
* ``sub``: subscribes to images (raw CDR, no Python deserialisation, so it costs little) and
  CameraInfo; prints ``R <stamp_ns> <receive_ns> <bytes>`` per image and
  ``I <stamp_ns> <fx> <finite>`` per CameraInfo.

    .venv/bin/python benchmarks/bench_common.py pub --width 1920 --height 1080 --encoding bgr8
    .venv/bin/python benchmarks/bench_common.py sub --topic image_rect

Every process uses ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, rmw_fastrtps_cpp and the project's
shared-memory Fast DDS profile (config/fastdds_shm.xml), in a ROS domain from 170 to 200.
"""
from __future__ import annotations

import argparse
import atexit
import os
import queue
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / 'benchmarks'
RESULTS = BENCH / 'results'
NODE_EXECUTABLE = REPO / 'install' / 'zeroshot_calib_ros' / 'lib' / 'zeroshot_calib_ros' / 'node'
RELAY = BENCH / 'relay_node.py'
DDS_PROFILE = REPO / 'config' / 'fastdds_shm.xml'
DOMAIN_FIRST, DOMAIN_LAST = 170, 200
PY = sys.executable

SIZES = {'640x480': (640, 480), '1280x720': (1280, 720), '1920x1080': (1920, 1080),
         '3840x2160': (3840, 2160)}
CHANNELS = {'bgr8': 3, 'mono8': 1}
# Spec of a wide action camera (the W1 of the tests): hfov 118, vfov from the aspect ratio.
HFOV = 118.0


def vfov_for(width, height):
    """vfov of the benchmark lens for a frame size: 69 deg at 16:9 (the GoPro HERO9 W1 of the
    tests), 90 deg for a 4:3 crop of the same lens."""
    return 69.0 if abs(width / height - 16 / 9) < 1e-6 else 90.0


def node_calibration(width, height, rectify=True):
    """The node's own ActiveCalibration for the benchmark lens at this frame size (the node's
    defaults and code path; needs the install tree, or the package, importable)."""
    from zeroshot_calib_ros.core.streaming.node_parameters import PARAMETERS, Settings, solve_from_settings
    values = {name: parameter.default for name, parameter in PARAMETERS.items()}
    values.update(width=width, height=height, hfov=HFOV, vfov=vfov_for(width, height), rectify=rectify)
    active, _ = solve_from_settings(Settings.from_values(values), 0)
    return active


def site_packages() -> Path:
    return REPO / 'install' / 'zeroshot_calib_ros' / 'lib' / \
        f'python{sys.version_info[0]}.{sys.version_info[1]}' / 'site-packages'


_domain_counter = [0]


def next_domain() -> int:
    """A ROS domain of its own for each case (170..200), so that stale participants of a
    previous case are never matched."""
    _domain_counter[0] += 1
    span = DOMAIN_LAST - DOMAIN_FIRST + 1
    return DOMAIN_FIRST + (os.getpid() + _domain_counter[0]) % span


def ros_env(domain_id: int) -> dict:
    env = dict(os.environ)
    pp = str(site_packages())
    env['PYTHONPATH'] = pp + (os.pathsep + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
    prefix = str(REPO / 'install' / 'zeroshot_calib_ros')
    env['AMENT_PREFIX_PATH'] = prefix + (os.pathsep + env['AMENT_PREFIX_PATH']
                                         if env.get('AMENT_PREFIX_PATH') else '')
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               RMW_IMPLEMENTATION='rmw_fastrtps_cpp', FASTDDS_DEFAULT_PROFILES_FILE=str(DDS_PROFILE),
               FASTRTPS_DEFAULT_PROFILES_FILE=str(DDS_PROFILE), PYTHONUNBUFFERED='1')
    env.pop('ROS_LOCALHOST_ONLY', None)
    return env


# --- child processes ------------------------------------------------------------------------
_children = []


def _stop_all():
    for child in list(_children):
        child.stop()


atexit.register(_stop_all)


def _on_term(signum, frame):
    _stop_all()
    sys.exit(128 + signum)


def install_signal_handlers():
    signal.signal(signal.SIGTERM, _on_term)
    signal.signal(signal.SIGHUP, _on_term)


class Child:
    """A child process whose stdout lines are read by a thread; stopped (SIGINT, then SIGKILL)
    at the latest when the benchmark exits."""

    def __init__(self, argv, env, name, stdin=False, log_dir=None, keep_lines=True):
        self.name = name
        self.argv = [str(a) for a in argv]
        self.lines = queue.Queue()
        self.keep_lines = keep_lines
        self.started_at = time.time_ns()
        self._stderr_path = None
        stderr = subprocess.STDOUT
        if log_dir is not None:
            self._stderr_path = Path(log_dir) / f'{name}.stderr.log'
            stderr = open(self._stderr_path, 'w')
        self.process = subprocess.Popen(self.argv, env=env, stdout=subprocess.PIPE, stderr=stderr,
                                        stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                                        text=True, bufsize=1, cwd=str(REPO))
        if stderr is not subprocess.STDOUT:
            stderr.close()
        _children.append(self)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.other = []  # lines that are not data

    @property
    def pid(self) -> int:
        return self.process.pid

    def _read(self):
        for line in self.process.stdout:
            self.lines.put(line.rstrip('\n'))
        self.lines.put(None)

    def send(self, text: str):
        self.process.stdin.write(text + '\n')
        self.process.stdin.flush()

    def wait_line(self, prefix: str, timeout: float, sink=None) -> str:
        """The next line starting with ``prefix``; other lines go to ``sink`` (a callable)."""
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f'{self.name}: no {prefix!r} line within {timeout:g} s')
            try:
                line = self.lines.get(timeout=min(remaining, 0.5))
            except queue.Empty:
                continue
            if line is None:
                raise RuntimeError(f'{self.name} exited ({self.process.poll()}) before {prefix!r}: '
                                   + ' | '.join(self.other[-10:]))
            if line.startswith(prefix):
                return line
            (sink or self.other.append)(line)

    def drain(self, sink):
        """Every line read so far, to ``sink``."""
        while True:
            try:
                line = self.lines.get_nowait()
            except queue.Empty:
                return
            if line is None:
                return
            sink(line)

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self, timeout: float = 8.0):
        if self in _children:
            _children.remove(self)
        if self.process.poll() is None:
            try:
                if self.process.stdin:
                    try:
                        self.process.stdin.write('QUIT\n')
                        self.process.stdin.flush()
                    except (BrokenPipeError, ValueError, OSError):
                        pass
                self.process.send_signal(signal.SIGINT)
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        for stream in (self.process.stdin, self.process.stdout):
            try:
                if stream:
                    stream.close()
            except OSError:
                pass


def proc_status(pid: int) -> dict:
    """VmRSS, VmHWM (peak RSS) and the RSS split (RssAnon: heap; RssFile: mapped libraries;
    RssShmem: shared memory, i.e. the Fast DDS segments) of a process, in MiB."""
    out = {}
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                key, _, value = line.partition(':')
                if key in ('VmRSS', 'VmHWM', 'RssAnon', 'RssFile', 'RssShmem'):
                    out[key] = int(value.split()[0]) / 1024.0
    except OSError:
        pass
    return out


def proc_counters(pid: int) -> tuple:
    """(minor page faults, CPU seconds) a process has used so far (/proc/PID/stat); NaNs once it
    has gone."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()  # after "pid (comm)": field 3 is fields[0]
    except OSError:
        return float('nan'), float('nan')
    return int(fields[7]), (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def machine_description() -> str:
    def run(cmd):
        try:
            return subprocess.run(cmd, shell=True, capture_output=True, text=True, timeout=10).stdout.strip()
        except Exception as exc:  # noqa: BLE001
            return f'({cmd}: {exc})'
    load = run('cat /proc/loadavg')
    return (f'$ nproc\n{run("nproc")}\n$ lscpu | head -n 14\n{run("lscpu | head -n 14")}\n'
            f'$ free -g\n{run("free -g")}\n/proc/loadavg at start: {load}')


def versions() -> str:
    import cv2
    import numpy
    return f'Python {sys.version.split()[0]}, numpy {numpy.__version__}, OpenCV {cv2.__version__}'


def percentile(values, q):
    import numpy as np
    return float(np.percentile(values, q)) if len(values) else float('nan')


# --- test frame -----------------------------------------------------------------------------
def test_image(width: int, height: int, channels: int):
    """A textured frame (checkerboard, gradients, fine noise): every remap does full work."""
    import numpy as np
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:height, 0:width]
    square = max(8, width // 24)
    board = (((xx // square) + (yy // square)) % 2) * 160 + 40
    base = board + (xx * 30 // max(1, width)) + rng.integers(0, 25, (height, width))
    base = np.clip(base, 0, 255).astype(np.uint8)
    if channels == 1:
        return base
    planes = [base, np.roll(base, square // 3, axis=1), 255 - base][:channels]
    return np.ascontiguousarray(np.stack(planes, axis=-1))


# --- the two helper roles -------------------------------------------------------------------
def _sensor_qos(depth):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def frames_in_heap():
    """The node's allocator settings in every process of a benchmark (publisher, subscriber,
    relays): each allocates a frame-sized block per frame, and glibc's default thresholds make
    that cost a page fault per page in some processes and none in others, at random
    (zeroshot_calib_ros/core/streaming/heap.py). The floors and the clients are then the same in
    every round, and the relay floor is not slowed by faults the node no longer takes."""
    from zeroshot_calib_ros.core.streaming.heap import keep_frames_in_heap
    return keep_frames_in_heap()


def run_pub(args):
    """Image publisher: waits for a subscriber, then runs the phases it is told on stdin."""
    frames_in_heap()
    import rclpy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image

    rclpy.init()
    node = rclpy.create_node('bench_image_pub')
    pub = node.create_publisher(Image, args.topic, _sensor_qos(5))
    channels = CHANNELS[args.encoding]
    image = test_image(args.width, args.height, channels)
    msg = Image()
    msg.header.frame_id = 'bench_camera'
    msg.height, msg.width = image.shape[:2]
    msg.encoding = args.encoding
    msg.step = image.strides[0]
    msg.data = image.tobytes()
    wire = bytearray(serialize_message(msg))
    assert wire[:2] == b'\x00\x01', 'expected little-endian CDR'
    deadline = time.monotonic() + args.match_timeout
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.02)
    print(f'READY {pub.get_subscription_count()}', flush=True)
    out = sys.stdout
    for line in sys.stdin:
        parts = line.split()
        if not parts or parts[0] == 'QUIT':
            break
        if parts[0] != 'RUN':
            continue
        rate, seconds = float(parts[1]), float(parts[2])
        period = 1.0 / rate if rate > 0 else 0.0
        count = max(1, int(round(seconds * rate))) if rate > 0 else None
        start = time.monotonic()
        sent = 0
        while True:
            if count is not None:
                if sent >= count:
                    break
                target = start + sent * period
                now = time.monotonic()
                if target > now:
                    time.sleep(target - now)
            elif time.monotonic() - start >= seconds:
                break
            stamp = time.time_ns()
            struct.pack_into('<iI', wire, 4, stamp // 1_000_000_000, stamp % 1_000_000_000)
            pub.publish(bytes(wire))
            sent += 1
            out.write(f'S {stamp}\n')
        out.write(f'DONE {sent} {time.monotonic() - start:.4f}\n')
        out.flush()
    node.destroy_node()
    rclpy.try_shutdown()


def parse_camera_info(raw: bytes):
    """(stamp ns, fx, whether every number is finite) of a serialised sensor_msgs/CameraInfo
    (little-endian CDR, as Fast DDS writes it on x86 and ARM)."""
    import math
    sec, nsec = struct.unpack_from('<iI', raw, 4)
    o = 12
    n, = struct.unpack_from('<I', raw, o)  # frame_id
    o = (o + 4 + n + 3) & ~3
    o += 8  # height, width
    n, = struct.unpack_from('<I', raw, o)  # distortion_model
    o = (o + 4 + n + 3) & ~3
    nd, = struct.unpack_from('<I', raw, o)
    o += 4
    o = 4 + ((o - 4 + 7) & ~7)  # doubles are 8-aligned from the CDR origin (after the 4-byte header)
    values = struct.unpack_from(f'<{nd + 30}d', raw, o)  # d, k[9], r[9], p[12]
    return sec * 1_000_000_000 + nsec, values[nd], all(map(math.isfinite, values))


def run_sub(args):
    """Image / CameraInfo subscriber printing stamps and receive times; also sets the node's
    parameters on command (``SET name value``, value parsed as a Python literal)."""
    import ast

    import rclpy
    import rclpy.executors
    from rclpy.parameter import Parameter
    from rcl_interfaces.srv import SetParameters
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image

    frames_in_heap()
    rclpy.init()
    node = rclpy.create_node('bench_image_sub')
    out = sys.stdout

    def on_image(raw: bytes):
        now = time.time_ns()
        sec, nsec = struct.unpack_from('<iI', raw, 4)
        write(f'R {sec * 1_000_000_000 + nsec} {now} {len(raw)}\n')

    def on_info(raw: bytes):  # raw CDR, parsed here in ~2 us: the image callbacks are not delayed
        now = time.time_ns()
        stamp, fx, finite = parse_camera_info(raw)
        write(f'I {stamp} {fx!r} {int(finite)} {now}\n')

    image_sub = None
    if args.topic != 'none':
        image_sub = node.create_subscription(Image, args.topic, on_image, _sensor_qos(args.depth), raw=True)
    if args.info_topic:
        if args.info_latched:  # what a late joiner uses: gets the last CameraInfo on matching
            info_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.TRANSIENT_LOCAL)
        else:  # best effort matches the node's publisher whichever reliability it has
            info_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=args.depth,
                                  reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
        node.create_subscription(CameraInfo, args.info_topic, on_info, info_qos, raw=True)
    client = node.create_client(SetParameters, f'/{args.target_node}/set_parameters')
    lock = threading.Lock()  # stdout is written from the executor and the stdin thread

    def write(text):
        with lock:
            out.write(text)
            out.flush()

    def on_response(name, sent, future):
        result = future.result().results[0]
        reason = (result.reason or '-').replace('\n', ' ')
        write(f'SETDONE {name} {sent} {time.time_ns()} {int(result.successful)} {reason}\n')

    matched = [image_sub is None]

    def check_matched():
        if not matched[0] and image_sub.get_publisher_count() > 0:
            matched[0] = True
            write('MATCHED\n')

    node.create_timer(0.1, check_matched)
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)

    def read_commands():
        for line in sys.stdin:
            if line.startswith('QUIT'):
                break
            if line.startswith('PING'):
                write('PONG\n')
            elif line.startswith('SET '):
                _, name, value = line.split(None, 2)
                set_parameter(name, ast.literal_eval(value.strip()))
        rclpy.try_shutdown()  # ends spin()

    def set_parameter(name, value):
        param = Parameter(name, value=value).to_parameter_msg()  # rclpy infers the type
        if not client.wait_for_service(timeout_sec=10.0):
            write(f'SETDONE {name} 0 0 0 no-service\n')
            return
        sent = time.time_ns()
        future = client.call_async(SetParameters.Request(parameters=[param]))
        future.add_done_callback(lambda f: on_response(name, sent, f))

    reader = threading.Thread(target=read_commands, daemon=True)
    reader.start()
    print('READY', flush=True)
    timer = threading.Timer(args.timeout, rclpy.try_shutdown)
    timer.daemon = True
    timer.start()
    try:
        executor.spin()
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    out.flush()
    rclpy.try_shutdown()


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('role', choices=['pub', 'sub'])
    p.add_argument('--width', type=int, default=1920)
    p.add_argument('--height', type=int, default=1080)
    p.add_argument('--encoding', default='bgr8', choices=sorted(CHANNELS))
    p.add_argument('--topic', default=None)
    p.add_argument('--info-topic', default='')
    p.add_argument('--info-latched', action='store_true', help='sub: reliable transient-local CameraInfo')
    p.add_argument('--target-node', default='zeroshot_calib', help='sub: node whose parameters SET sets')
    p.add_argument('--depth', type=int, default=20)
    p.add_argument('--match-timeout', type=float, default=20.0)
    p.add_argument('--timeout', type=float, default=3600.0, help='sub: exit after this long regardless')
    args = p.parse_args()
    signal.signal(signal.SIGINT, lambda *a: (_ for _ in ()).throw(KeyboardInterrupt()))
    try:
        if args.role == 'pub':
            args.topic = args.topic or 'image_raw'
            run_pub(args)
        else:
            args.topic = args.topic or 'image_rect'
            run_sub(args)
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == '__main__':
    sys.exit(main())
