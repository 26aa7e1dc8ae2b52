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

``--imports REF``: instead, the import of the node module in a fresh interpreter (median of
``--trials``) for REF's committed package as exported (no .pyc: what ``make build`` installed on
machines with PYTHONDONTWRITEBYTECODE before the build compiled it), REF's byte-compiled, and the
install tree; and ``node --help`` (the executable's start-up before rclpy.init) through the
installed wrapper against setuptools' easy-install wrapper of the same module.
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


EASY_INSTALL_WRAPPER = """#!{python}
# EASY-INSTALL-ENTRY-SCRIPT: 'zeroshot-calib-ros==0.1.0','console_scripts','node'
import re
import sys
__requires__ = 'zeroshot-calib-ros==0.1.0'
from importlib.metadata import distribution


def load_entry_point(spec, group, name):
    dist_name, _, _ = spec.partition('==')
    matches = (entry_point for entry_point in distribution(dist_name).entry_points
               if entry_point.group == group and entry_point.name == name)
    return next(matches).load()


if __name__ == '__main__':
    sys.argv[0] = re.sub(r'(-script\\.pyw?|\\.exe)?$', '', sys.argv[0])
    sys.exit(load_entry_point('zeroshot-calib-ros==0.1.0', 'console_scripts', 'node')())
"""
"""What setuptools' install writes for a console script (setuptools 79, importlib.metadata branch)."""


def imports(ref: str, trials: int) -> int:
    import compileall
    import tempfile
    site = next((TOP / 'install' / 'zeroshot_calib_ros' / 'lib').glob('python3*/site-packages'))
    with tempfile.TemporaryDirectory() as tmp:
        exported, compiled = Path(tmp) / 'exported', Path(tmp) / 'compiled'
        archive = subprocess.run(['git', '-C', str(TOP), 'archive', ref, 'zeroshot_calib_ros'], check=True,
                                 capture_output=True).stdout
        for d in (exported, compiled):
            d.mkdir()
            subprocess.run(['tar', '-x', '-C', str(d)], input=archive, check=True)
        compileall.compile_dir(str(compiled), quiet=1)
        easy = Path(tmp) / 'node'
        easy.write_text(EASY_INSTALL_WRAPPER.format(python=sys.executable))
        easy.chmod(0o755)
        code = ("import sys; sys.path.insert(0, {d!r}); import time; t = time.perf_counter(); "
                "import zeroshot_calib_ros.ros.node as n; assert n.__file__.startswith({d!r}); "
                "print(time.perf_counter() - t)")
        cases = {f'{ref} as exported (no .pyc)': exported, f'{ref} byte-compiled': compiled, 'install tree': site}
        times = {name: [] for name in cases}
        helps = {'installed wrapper': [], 'easy-install wrapper': []}
        for _ in range(trials):
            for name, d in cases.items():
                out = subprocess.run([sys.executable, '-c', code.format(d=str(d))], capture_output=True, text=True,
                                     cwd='/', check=True).stdout
                times[name].append(float(out))
            for name, exe in (('installed wrapper', NODE), ('easy-install wrapper', easy)):
                t0 = time.perf_counter()
                done = subprocess.run([str(exe), '--help'], capture_output=True, text=True)
                helps[name].append(time.perf_counter() - t0)
                assert done.returncode == 0 and 'ros2 run' in done.stdout, done.stderr[-500:]
    for name, values in times.items():
        print(f'import zeroshot_calib_ros.ros.node, {name}: median {statistics.median(values):.3f} s')
    for name, values in helps.items():
        print(f'node --help through the {name}: median {statistics.median(values):.3f} s')
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--trials', type=int, default=12)
    parser.add_argument('--width', type=int, default=1920)
    parser.add_argument('--height', type=int, default=1080)
    parser.add_argument('--rectify', action='store_true', help='start the node with rectify:=true')
    parser.add_argument('--imports', metavar='REF', help='measure the import of the node module against REF instead')
    parser.add_argument('--trial', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.imports:
        return imports(args.imports, args.trials)
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
