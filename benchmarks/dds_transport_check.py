#!/usr/bin/env python3
"""Check that large best-effort images cross between two processes.

Starts a subscriber process and a publisher process (same ROS_DOMAIN_ID,
rmw_fastrtps_cpp, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST).  The publisher
sends sensor_msgs/Image frames with qos_profile_sensor_data (best effort) at
a fixed rate for a few seconds; the subscriber counts complete frames.  Each
case runs once with the Fast DDS profile (FASTDDS_DEFAULT_PROFILES_FILE) and
once without, and prints received/sent.

    .venv/bin/python benchmarks/dds_transport_check.py
    .venv/bin/python benchmarks/dds_transport_check.py --sizes 1920x1080 \
        --profile config/fastdds_shm.xml --modes profile

Every child is bounded in time and killed if it overruns.
"""

import argparse
import os
import random
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_PROFILE = os.path.join(os.path.dirname(HERE), 'config', 'fastdds_shm.xml')
TOPIC = 'dds_transport_check/image'


def _qos():
    from rclpy.qos import qos_profile_sensor_data
    return qos_profile_sensor_data


def run_sub(args):
    import rclpy
    from sensor_msgs.msg import Image

    rclpy.init()
    node = rclpy.create_node('dds_check_sub')
    expected = args.width * args.height * 3
    stats = {'frames': 0, 'bad': 0, 'last': None}

    def on_msg(raw):
        # raw=True: serialized CDR bytes, no Python deserialisation cost, so
        # the count measures the transport.  A complete frame is > W*H*3.
        if len(raw) >= expected:
            stats['frames'] += 1
        else:
            stats['bad'] += 1
        stats['last'] = time.monotonic()

    node.create_subscription(Image, TOPIC, on_msg, _qos(), raw=True)
    print('READY', flush=True)
    deadline = time.monotonic() + args.timeout
    done_seen = None
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        now = time.monotonic()
        if done_seen is None and os.path.exists(args.done_file):
            done_seen = now
        # publisher finished: drain what is still in flight, then stop
        if done_seen is not None and now - max(done_seen, stats['last'] or 0) > 1.5:
            break
    print(f"RECEIVED {stats['frames']} BAD {stats['bad']}", flush=True)
    node.destroy_node()
    rclpy.shutdown()


def run_pub(args):
    import rclpy
    from sensor_msgs.msg import Image

    rclpy.init()
    node = rclpy.create_node('dds_check_pub')
    pub = node.create_publisher(Image, TOPIC, _qos())
    msg = Image()
    msg.header.frame_id = 'camera'
    msg.height, msg.width = args.height, args.width
    msg.encoding = 'bgr8'
    msg.step = args.width * 3
    msg.data = bytes(random.Random(0).getrandbits(8) for _ in range(256)) * (
        args.width * args.height * 3 // 256)
    # wait for the subscriber to be matched (bounded)
    t0 = time.monotonic()
    while pub.get_subscription_count() < 1 and time.monotonic() - t0 < args.match_timeout:
        rclpy.spin_once(node, timeout_sec=0.05)
    matched = pub.get_subscription_count() >= 1
    time.sleep(0.5)  # let the reader side finish matching too
    period = 1.0 / args.rate
    n = int(round(args.duration * args.rate))
    start = time.monotonic()
    sent = 0
    for i in range(n):
        target = start + i * period
        now = time.monotonic()
        if target > now:
            time.sleep(target - now)
        msg.header.stamp = node.get_clock().now().to_msg()
        pub.publish(msg)
        sent += 1
    elapsed = time.monotonic() - start
    print(f'SENT {sent} MATCHED {int(matched)} ELAPSED {elapsed:.2f}', flush=True)
    node.destroy_node()
    rclpy.shutdown()


def _field(out, key):
    toks = out.split()
    for i, tok in enumerate(toks[:-1]):
        if tok == key:
            return toks[i + 1]
    return None


def run_case(width, height, profile, args, fastdds_var_only=False):
    env = dict(os.environ)
    env['RMW_IMPLEMENTATION'] = 'rmw_fastrtps_cpp'
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = args.discovery_range
    env['ROS_DOMAIN_ID'] = str(random.randint(100, 200))
    for var in ('FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE'):
        env.pop(var, None)
    if profile:
        env['FASTDDS_DEFAULT_PROFILES_FILE'] = profile
        if not fastdds_var_only:
            # Fast DDS 2.14 (Jazzy) reads only this one
            env['FASTRTPS_DEFAULT_PROFILES_FILE'] = profile
    else:
        # do not pick up a DEFAULT_FASTRTPS_PROFILES.xml from the cwd
        env['SKIP_DEFAULT_XML_FILE'] = '1'
    done_file = f'/tmp/dds_check_done_{os.getpid()}_{width}x{height}_{bool(profile)}'
    if os.path.exists(done_file):
        os.remove(done_file)
    common = [sys.executable, os.path.abspath(__file__),
              '--width', str(width), '--height', str(height),
              '--rate', str(args.rate), '--duration', str(args.duration),
              '--done-file', done_file]
    budget = args.duration + 25.0
    sub = subprocess.Popen(common + ['--role', 'sub', '--timeout', str(budget)],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True)
    # wait for READY (bounded: the subscriber is killed if it hangs)
    watchdog = threading.Timer(30.0, sub.kill)
    watchdog.start()
    ready_line = sub.stdout.readline()
    watchdog.cancel()
    if 'READY' not in ready_line:
        sub.kill()
        return None, None, 'subscriber failed: ' + sub.stderr.read()[-500:]
    try:
        pub = subprocess.run(common + ['--role', 'pub'], env=env, capture_output=True,
                             text=True, timeout=budget)
        pub_out, pub_err = pub.stdout, pub.stderr
    except subprocess.TimeoutExpired:
        pub_out, pub_err = '', 'publisher timed out'
    with open(done_file, 'w'):
        pass
    try:
        sub_out, sub_err = sub.communicate(timeout=budget)
    except subprocess.TimeoutExpired:
        sub.kill()
        sub_out, sub_err = sub.communicate()
    os.remove(done_file)
    sent = _field(pub_out, 'SENT')
    received = _field(sub_out, 'RECEIVED')
    note = ''
    if _field(pub_out, 'ELAPSED'):
        note = f"publisher took {_field(pub_out, 'ELAPSED')} s"
    if _field(sub_out, 'BAD') not in (None, '0'):
        note += f", {_field(sub_out, 'BAD')} truncated"
    if _field(pub_out, 'MATCHED') == '0':
        note = 'publisher never matched the subscriber'
    if sent is None or received is None:
        note = (pub_err + sub_err)[-800:]
    return (int(received) if received else None), (int(sent) if sent else None), note


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--role', choices=['sub', 'pub'])
    p.add_argument('--width', type=int, default=1920)
    p.add_argument('--height', type=int, default=1080)
    p.add_argument('--rate', type=float, default=30.0)
    p.add_argument('--duration', type=float, default=3.0)
    p.add_argument('--timeout', type=float, default=30.0)
    p.add_argument('--match-timeout', type=float, default=10.0)
    p.add_argument('--done-file', default='')
    p.add_argument('--sizes', default='1920x1080,3840x2160')
    p.add_argument('--profile', default=DEFAULT_PROFILE)
    p.add_argument('--discovery-range', default='LOCALHOST',
                   help='ROS_AUTOMATIC_DISCOVERY_RANGE for the two processes')
    p.add_argument('--modes', default='profile,default',
                   help='comma list of: profile (with --profile), default (no XML), '
                   'fastdds-var-only (profile named by FASTDDS_DEFAULT_PROFILES_FILE only)')
    args = p.parse_args()
    if args.role == 'sub':
        return run_sub(args)
    if args.role == 'pub':
        return run_pub(args)

    profile = os.path.abspath(args.profile)
    print(f'rate {args.rate:g} Hz, {args.duration:g} s, best effort '
          f'(qos_profile_sensor_data), bgr8; profile: {profile}')
    for size in args.sizes.split(','):
        w, h = (int(v) for v in size.lower().split('x'))
        for mode in args.modes.split(','):
            received, sent, note = run_case(
                w, h, None if mode == 'default' else profile, args,
                fastdds_var_only=(mode == 'fastdds-var-only'))
            label = {'profile': 'with profile', 'default': 'without profile'}.get(mode, mode)
            print(f'{w}x{h} {label:16s} received/sent = {received}/{sent}'
                  + (f'  ({note.strip()})' if note else ''), flush=True)


if __name__ == '__main__':
    sys.exit(main())
