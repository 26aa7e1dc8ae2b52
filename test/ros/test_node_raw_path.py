"""The node's serialized frame path (issue 14), seen from another process: it is the path in use
(its start-up log and /diagnostics say so), what it publishes is what the message path publishes
(ZEROSHOT_CALIB_FRAME_PATH=message, the previous node) byte for byte for every encoding, frame
layout and header, and malformed serialized frames are skipped and counted on it."""
import struct

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo, Image

from ros_peer import diagnostics_value, domain_id, image_msg, peer, qos, start_node  # noqa: F401
from zeroshot_calib_ros.core.streaming.image_frames import ENCODINGS

SPEC = ['-p', 'width:=64', '-p', 'height:=36', '-p', 'hfov:=118', '-p', 'vfov:=69', '-p', 'rectify:=true']
RELIABLE = qos(ReliabilityPolicy.RELIABLE, depth=100)
FRAME_IDS = ['', 'a', 'ab', 'abc', 'camera_optical', 'kamera_\u00e9']


def stamp_of(raw: bytes) -> int:
    sec, nanosec = struct.unpack_from('<iI', raw, 4)
    return sec * 1_000_000_000 + nanosec


def _pad(positions, offset, size):
    """Padding positions that bring ``offset`` (in the buffer) to a multiple of ``size`` after
    the 4-byte encapsulation header; returns the aligned offset."""
    while (offset - 4) % size:
        positions.add(offset)
        offset += 1
    return offset


def padding_positions(msg) -> set:
    """Where CDR alignment padding lies in a serialized Image / CameraInfo (Fast CDR leaves those
    bytes as they were in memory, so two serializations of one message may differ there only)."""
    positions = set()
    offset = 4 + 8 + 4 + len(msg.header.frame_id.encode()) + 1
    offset = _pad(positions, offset, 4) + 8  # height, width
    if isinstance(msg, Image):
        offset += 4 + len(msg.encoding.encode()) + 1 + 1  # encoding, is_bigendian
        _pad(positions, offset, 4)
    else:
        offset += 4 + len(msg.distortion_model.encode()) + 1
        offset = _pad(positions, offset, 4) + 4  # the length of d
        _pad(positions, offset, 8)
    return positions


def assert_same_message(ours: bytes, theirs: bytes, msg_type, zero_padding=True):
    """The same message, the same bytes outside the padding (ours zero there, as the serialized
    path writes it, unless the message path serialized ours too)."""
    msg = deserialize_message(ours, msg_type)
    assert msg == deserialize_message(theirs, msg_type)
    assert len(ours) == len(theirs)
    padding = padding_positions(msg)
    differ = [i for i in range(len(ours)) if ours[i] != theirs[i] and i not in padding]
    assert not differ, f'{msg_type.__name__} bytes differ at {differ[:10]}'
    if zero_padding:
        assert all(ours[i] == 0 for i in padding)


def texture(shape, dtype, seed):
    rng = np.random.default_rng(seed)
    if np.dtype(dtype).kind == 'f':
        return (rng.random(shape) * 5 + 0.5).astype(dtype)
    return rng.integers(0, np.iinfo(dtype).max, shape, dtype, endpoint=True)


def test_serialized_path_is_in_use_and_publishes_the_message_paths_bytes(peer, start_node, monkeypatch):
    """One frame of every encoding (textured; frame_ids of every padding case; a big-endian
    16-bit frame; a padded step; a Bayer frame, which gets its CameraInfo only), plus two frames
    the serialized reader hands to the deserializer (an XCDR2 encapsulation header, a frame_id
    that is not UTF-8), go to a node on each path. Each image_rect and CameraInfo of the
    serialized path is the message path's, deserialized and byte for byte."""
    monkeypatch.setenv('ZEROSHOT_CALIB_FRAME_PATH', 'message')
    previous = start_node('--ros-args', *SPEC, '-r', '__ns:=/msg', '-r', '__node:=zeroshot_calib_msg', name='msg')
    monkeypatch.delenv('ZEROSHOT_CALIB_FRAME_PATH')
    node = start_node('--ros-args', *SPEC)
    outputs = {}
    for topic in ('image_rect', 'camera_info', '/msg/image_rect', '/msg/camera_info'):
        received = outputs[topic] = {}
        peer.node.create_subscription(Image if 'image' in topic else CameraInfo, topic,
                                      lambda raw, r=received: r.setdefault(stamp_of(raw), raw), RELIABLE, raw=True)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pubs = [peer.image_publisher(RELIABLE, 'image_raw'), peer.image_publisher(RELIABLE, '/msg/image_raw')]

    def send(raw):
        for pub in pubs:
            pub.publish(raw)

    warm = 49_000_000_000
    send(serialize_message(image_msg(texture((36, 64), np.uint8, 0), 'mono8', warm)))
    peer.spin_until(lambda: warm in outputs['image_rect'] and warm in outputs['/msg/image_rect'],
                    what='both nodes rectifying')
    frames = []  # (serialized frame, rectified?)
    for i, (encoding, (dtype, channels)) in enumerate(ENCODINGS.items()):
        shape = (36, 64) if channels == 1 else (36, 64, channels)
        msg = image_msg(texture(shape, dtype, i), encoding, 50_000_000_000 + i, frame_id=FRAME_IDS[i % 6])
        frames.append((serialize_message(msg), True))
    big = image_msg(texture((36, 64), np.uint16, 20).astype('>u2'), 'mono16', 50_000_000_100, frame_id='be')
    big.is_bigendian = 1
    padded = image_msg(np.pad(texture((36, 64, 3), np.uint8, 21), ((0, 0), (0, 3), (0, 0))), 'bgr8',
                       50_000_000_101, frame_id='pad')
    padded.width = 64  # step 201 > 192: rows carry 9 bytes after the pixels
    bayer = image_msg(texture((36, 64), np.uint8, 22), 'bayer_rggb8', 50_000_000_102)
    frames += [(serialize_message(big), True), (serialize_message(padded), True), (serialize_message(bayer), False)]
    xcdr2 = bytearray(serialize_message(image_msg(texture((36, 64), np.uint8, 23), 'mono8', 50_000_000_103)))
    xcdr2[1] = 0x07  # CDR2 little-endian: the same bytes for a type without 8-byte fields
    not_utf8 = bytearray(serialize_message(image_msg(texture((36, 64), np.uint8, 24), 'mono8', 50_000_000_104,
                                                     frame_id='ab')))
    not_utf8[16:18] = b'\xff\xfe'
    frames += [(bytes(xcdr2), True), (bytes(not_utf8), True)]
    for raw, _ in frames:
        send(raw)
        peer.spin_for(0.05)
    stamps = [stamp_of(raw) for raw, _ in frames]
    rectified = [stamp_of(raw) for raw, rect in frames if rect]
    peer.spin_until(lambda: all(set(rectified) <= set(outputs[t]) for t in ('image_rect', '/msg/image_rect')) and
                    all(set(stamps) <= set(outputs[t]) for t in ('camera_info', '/msg/camera_info')),
                    what='every output of both nodes')
    handed_over = {50_000_000_103, 50_000_000_104}
    for stamp in stamps:
        assert_same_message(outputs['camera_info'][stamp], outputs['/msg/camera_info'][stamp], CameraInfo,
                            stamp not in handed_over)
    for stamp in rectified:
        assert_same_message(outputs['image_rect'][stamp], outputs['/msg/image_rect'][stamp], Image,
                            stamp not in handed_over)
    assert 50_000_000_102 not in outputs['image_rect'] and 50_000_000_102 in outputs['camera_info']  # Bayer
    be = deserialize_message(outputs['image_rect'][50_000_000_100], Image)
    assert be.is_bigendian == 0 and be.step == 128  # converted to the host's order, rows packed
    assert deserialize_message(outputs['camera_info'][50_000_000_104], CameraInfo).header.frame_id == '\ufffd\ufffd'

    def status(name):
        for msg in reversed(diagnostics):
            for s in msg.status:
                if s.name == f'{name}: calibration':
                    return {kv.key: kv.value for kv in s.values}
        return None

    peer.spin_until(lambda: (status('zeroshot_calib') or {}).get('frames_via_message_path') == '2' and
                    status('zeroshot_calib_msg') is not None, timeout=5, what='diagnostics of both nodes')
    assert status('zeroshot_calib')['frame_path'] == 'serialized'
    assert status('zeroshot_calib_msg')['frame_path'] == 'message (ZEROSHOT_CALIB_FRAME_PATH=message)'
    assert 'frames_via_message_path' not in status('zeroshot_calib_msg')
    assert '  frame path serialized: image_raw taken as CDR bytes' in node.log
    assert '  frame path message: sensor_msgs/Image objects (ZEROSHOT_CALIB_FRAME_PATH=message)' in previous.log
    assert 'frame taken on the message path: encapsulation 0007' in node.log
    assert node.alive() and previous.alive() and 'Traceback' not in node.log + previous.log


def test_malformed_serialized_frames_are_skipped_and_counted_on_the_serialized_path(peer, start_node):
    """The malformed frames of test_node.py and test_reliability.py, and serialized ones no
    sensor_msgs/Image could carry (data shorter than its length says, a frame_id longer than the
    message, garbage after a valid encapsulation header), on the serialized path: each counted as
    malformed (none handed to the deserializer), none rectified, none with a CameraInfo but the
    16-bit frame whose step splits a pixel (its data is all there, as check_frame wants; only
    rectification refuses it), the node alive, the next good frame rectified."""
    node = start_node('--ros-args', *SPEC)
    rects = peer.collect(Image, 'image_rect', RELIABLE)
    infos = peer.collect(CameraInfo, 'camera_info', RELIABLE)
    diagnostics = peer.collect(DiagnosticArray, '/diagnostics', qos())
    pub = peer.image_publisher(RELIABLE)
    good = texture((36, 64, 3), np.uint8, 1)
    short = image_msg(good, 'bgr8', 60)
    short.data = short.data[:-10]
    bad_step = image_msg(good, 'bgr8', 61)
    bad_step.step = 100
    empty = image_msg(np.zeros((0, 0), np.uint8), 'mono8', 62)
    odd_step = image_msg(np.zeros((36, 64), np.uint16), 'mono16', 63)
    odd_step.step, odd_step.data = 129, bytes(129 * 36)
    huge = image_msg(np.zeros((9, 16), np.uint8), 'mono8', 64)
    huge.width, huge.height, huge.step = 64000, 36000, 64000
    frames = [serialize_message(m) for m in (short, bad_step, empty, odd_step, huge)]
    truncated = serialize_message(image_msg(good, 'bgr8', 65))[:-100]  # data length says 100 bytes more
    long_frame_id = bytearray(serialize_message(image_msg(good, 'bgr8', 66)))
    long_frame_id[12:16] = struct.pack('<I', len(long_frame_id))
    garbage = b'\x00\x01\x00\x00' + struct.pack('<iI', 0, 67) + np.random.default_rng(2).bytes(300)
    frames += [truncated, bytes(long_frame_id), garbage]
    for raw in frames:
        pub.publish(raw)
        peer.spin_for(0.05)
    pub.publish(serialize_message(image_msg(good, 'bgr8', 68)))
    peer.spin_until(lambda: any(m.header.stamp.nanosec == 68 for m in rects), what='the good frame rectified')
    peer.spin_until(lambda: diagnostics_value(diagnostics, 'frames_skipped_malformed') == str(len(frames)),
                    what='every malformed frame counted')
    assert diagnostics_value(diagnostics, 'frames_via_message_path') is None
    assert diagnostics_value(diagnostics, 'frame_path') == 'serialized'
    assert {m.header.stamp.nanosec for m in infos} & set(range(60, 68)) == {63}
    assert not {m.header.stamp.nanosec for m in rects} & set(range(60, 68))
    assert node.alive() and 'Traceback' not in node.log


def test_the_benchmarks_remap_relay_publishes_the_nodes_camera_info_then_the_rectified_frame():
    """benchmarks/relay_node.py --mode remap, the stream floor the node's latency and rate are
    measured against (benchmarks/rectify_throughput.py): per frame, the node's CameraInfo with the
    frame's header, then the serialized Image the node publishes (the frame's header, the node's
    rectification of its pixels) from the node's SerializedImage, reused frame after frame. No DDS here: its
    callback is called with serialized frames and publishers that keep what they are given."""
    import sys
    from pathlib import Path
    from types import SimpleNamespace
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'benchmarks'))
    import bench_common
    import relay_node
    from zeroshot_calib_ros.core.ros_formats.cdr_image import SerializedImage
    from zeroshot_calib_ros.ros.messages import fill_camera_info

    published = []

    class Handle:
        def __init__(self, topic):
            self.topic = topic

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def publish_raw(self, buffer):
            published.append((self.topic, bytes(buffer)))  # copied, as the middleware copies before returning

    calibration, rectifier = bench_common.node_calibration(64, 36).for_size(64, 36)
    relay = SimpleNamespace(_rectifier=rectifier, _calibration=calibration, _rect=SerializedImage(), _info=None, count=0,
                            _pub=SimpleNamespace(handle=Handle('image_rect')),
                            _info_pub=SimpleNamespace(handle=Handle('camera_info')))
    frames = [image_msg(texture((36, 64), np.uint8, 30), 'mono8', 60_000_000_000, frame_id='a'),
              image_msg(texture((36, 64), np.uint8, 31), 'mono8', 60_000_000_001, frame_id='b'),
              image_msg(texture((36, 64, 3), np.uint8, 32), 'bgr8', 60_000_000_002, frame_id='camera_optical')]
    buffers = []
    for msg in frames:
        relay_node.Relay._on_image_remapped(relay, serialize_message(msg))
        buffers.append(relay._rect.buffer)
    assert relay.count == 3 and buffers[0] is buffers[1] and buffers[2] is not buffers[1]  # reused per layout
    assert [topic for topic, _ in published] == ['camera_info', 'image_rect'] * 3
    for msg, (_, info), (_, ours) in zip(frames, published[0::2], published[1::2]):
        expected_info = CameraInfo()
        fill_camera_info(expected_info, calibration)
        expected_info.header = msg.header
        assert_same_message(info, serialize_message(expected_info), CameraInfo)
        pixels = np.frombuffer(bytes(msg.data), np.uint8).reshape((msg.height, msg.width, -1)).squeeze()
        expected = image_msg(rectifier.rectify(pixels), msg.encoding, stamp_of(serialize_message(msg)),
                             frame_id=msg.header.frame_id)
        assert_same_message(ours, serialize_message(expected), Image)  # the frame's header, padding zero
    assert deserialize_message(published[1][1], Image).data != frames[0].data  # remapped, not passed through


def _faults_per_frame(peer, node, frames: int) -> float:
    """The node process's minor page faults per 1080p bgr8 frame it rectifies, frames sent one
    at a time (each after the previous image_rect came back), once it rectifies."""
    rects = set()
    peer.node.create_subscription(Image, 'image_rect', lambda raw: rects.add(stamp_of(raw)), RELIABLE, raw=True)
    pub = peer.image_publisher(RELIABLE)
    pixels = texture((1080, 1920, 3), np.uint8, 7)

    def send(stamp):
        pub.publish(serialize_message(image_msg(pixels, 'bgr8', stamp)))
        peer.spin_until(lambda: stamp in rects, timeout=60, what=f'image_rect of frame {stamp}')

    for i in range(3):  # frames before the maps are built are not rectified: a few, then one for sure
        pub.publish(serialize_message(image_msg(pixels, 'bgr8', 70_000_000_000 + i)))
        peer.spin_for(1.0)
    send(71_000_000_000)

    def minflt():
        with open(f'/proc/{node.process.pid}/stat') as f:
            return int(f.read().rsplit(')', 1)[1].split()[7])

    before = minflt()
    for i in range(frames):
        send(72_000_000_000 + i)
    return (minflt() - before) / frames


def test_a_stream_of_frames_costs_the_node_no_page_faults(peer, start_node, monkeypatch):
    """1080p bgr8 frames through the node: once it rectifies, a frame costs it no page faults
    (core/streaming/heap.py: the frame taken and the frame published stay in the heap), and its
    start-up log says so. Beside it, the same node under a user's MALLOC_MMAP_THRESHOLD_ (the
    user's setting wins, and the log says that) faults every frame's pages in: what the node did
    at random before, and what this measurement sees when it happens."""
    import os

    import pytest
    if not os.path.exists('/proc/self/stat'):
        pytest.skip('page faults are read from /proc/PID/stat (Linux)')
    spec = ['--ros-args', '-p', 'width:=1920', '-p', 'height:=1080', '-p', 'hfov:=118', '-p', 'vfov:=69',
            '-p', 'rectify:=true']
    node = start_node(*spec)
    kept = _faults_per_frame(peer, node, 12)
    assert '  memory     frames up to 32 MiB reused from the heap (glibc mmap threshold 32 MiB, ' \
           'trim threshold 64 MiB)' in node.log
    node.stop()

    monkeypatch.setenv('MALLOC_MMAP_THRESHOLD_', str(128 << 10))  # glibc's own default, fixed by the user
    tuned = start_node(*spec, name='tuned')
    faults = _faults_per_frame(peer, tuned, 12)
    assert faults > 1500, faults  # 1,519 pages a frame; taken and published: about twice that
    # The node's own frames fault no pages in: what remains per frame is the rest of the process
    # (timers, DDS, Python objects; 20-130 pages, more on a busy machine, where each frame takes
    # longer), far below one frame's 1,519 pages and a tenth of what the same node faults in when
    # its frames are not kept in the heap.
    assert kept < 1519 / 4 and kept < faults / 10, (kept, faults)
    assert '  memory     allocator as the environment sets it (MALLOC_MMAP_THRESHOLD_)' in tuned.log
    assert tuned.alive() and 'Traceback' not in node.log + tuned.log
