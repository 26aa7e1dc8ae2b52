#!/usr/bin/env python3
"""The node's `refine` under a 30 fps 1080p stream: frames lost with refine on against off, in
the same run (the machine is shared: cases alternate, off / on / off / on ...), and how long the
node streams before it adopts a refined calibration.

A publisher process streams one frame rendered (test/scenes.py) through a known wide camera
(Kannala-Brandt, 1920x1080, principal point 21 px right of and 12 px above the centre, FOVs
172 / 97 / 198 degrees) at 30 fps, best effort, bgr8, as camera drivers do; the node rectifies
(rectify:=true, its heaviest work per frame) and a subscriber process counts image_rect and
camera_info per stamp. Lost = frames sent whose image_rect (or CameraInfo) never arrived.
Adoption is seen in CameraInfo: the first one whose fx differs from the spec's, timed from the
first frame the node was sent (the warm-up included: the refiner can adopt within it); the
refiner goes on after it (only a clearly better fit is adopted again), so the table counts the
changes of fx. Frames lost count the measured stream only.

    .venv/bin/python benchmarks/refine_node.py                # 2 rounds of 45 s per case
    .venv/bin/python benchmarks/refine_node.py --seconds 30 --rounds 1 --write

Writes benchmarks/results/refine_node.md with --write (the command, `uptime` before and
after, the table).
"""
from __future__ import annotations

import argparse
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_common as bc  # noqa: E402

COMMON = bc.BENCH / 'bench_common.py'
RESULT = bc.RESULTS / 'refine_node.md'
WIDTH, HEIGHT = 1920, 1080
SPEC = {'width': WIDTH, 'height': HEIGHT, 'hfov': 172.0, 'vfov': 97.0, 'dfov': 198.0}
FRAME_CACHE = Path(tempfile.gettempdir()) / 'zeroshot_refine_node_frame_1080.npy'


def true_camera():
    sys.path.insert(0, str(bc.REPO))
    from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera
    return KannalaBrandtCamera(630.0, 630.0, 981.0, 528.0, WIDTH, HEIGHT, np.array([0.02, -0.01, 0.003, -0.0005]))


def frame() -> np.ndarray:
    """The room of test/scenes.py through the true camera, BGR (rendered once, cached)."""
    if FRAME_CACHE.exists():
        return np.load(FRAME_CACHE)
    sys.path[:0] = [str(bc.REPO), str(bc.REPO / 'test')]
    from scenes import render
    grey = render(true_camera(), 'room', seed=1)[0]
    image = np.ascontiguousarray(np.repeat(grey[..., None], 3, axis=2))
    np.save(FRAME_CACHE, image)
    return image


def run_pub(args):
    """Publisher role: the rendered frame, best effort, stamped with the wall clock per frame."""
    import rclpy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image
    rclpy.init()
    node = rclpy.create_node('refine_bench_pub')
    pub = node.create_publisher(Image, 'image_raw', bc._sensor_qos(5))
    image = np.load(args.frame)
    msg = Image()
    msg.header.frame_id = 'bench_camera'
    msg.height, msg.width = image.shape[:2]
    msg.encoding = 'bgr8'
    msg.step = image.strides[0]
    msg.data = image.tobytes()
    wire = bytearray(serialize_message(msg))
    deadline = time.monotonic() + 20
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.02)
    print(f'READY {pub.get_subscription_count()}', flush=True)
    for line in sys.stdin:
        parts = line.split()
        if not parts or parts[0] == 'QUIT':
            break
        rate, seconds = float(parts[1]), float(parts[2])
        count, start, sent = int(round(rate * seconds)), time.monotonic(), 0
        while sent < count:
            wait = start + sent / rate - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            stamp = time.time_ns()
            struct.pack_into('<iI', wire, 4, stamp // 1_000_000_000, stamp % 1_000_000_000)
            pub.publish(bytes(wire))
            sent += 1
            sys.stdout.write(f'S {stamp}\n')
        sys.stdout.write(f'DONE {sent} {time.monotonic() - start:.4f}\n')
        sys.stdout.flush()
    node.destroy_node()
    rclpy.try_shutdown()


def node_argv(refine: bool, interval: float, package_dir):
    params = {**SPEC, 'rectify': True, 'refine': refine, 'refine_interval': interval,
              'camera_info_url': f'file://{tempfile.mkdtemp(prefix="refine_bench_")}/camera.yaml'}
    if package_dir:
        code = (f'import sys; sys.path.insert(0, {str(package_dir)!r}); '
                'from zeroshot_calib_ros.ros.node import main; sys.exit(main())')
        argv = [bc.PY, '-P', '-c', code, '--ros-args']
    else:
        argv = [str(bc.NODE_EXECUTABLE), '--ros-args']
    for k, v in params.items():
        argv += ['-p', f'{k}:={str(v).lower() if isinstance(v, bool) else v}']
    return argv


def run_case(refine: bool, seconds: float, rate: float, interval: float, log_dir: Path, package_dir, tag: str,
             paused: bool = False):
    """One case; ``paused``: the refine worker is stopped (SIGSTOP) once started, which tells the
    node's own share of the cost (threads, the frame handed over) from the worker's CPU."""
    env = bc.ros_env(bc.next_domain())
    images, infos, sent, warm_sent, warm_infos = {}, {}, [], [], {}
    sub = bc.Child([bc.PY, COMMON, 'sub', '--topic', 'image_rect', '--info-topic', 'camera_info'], env,
                   f'{tag}-sub', stdin=True, log_dir=log_dir)
    sub.wait_line('READY', 60)
    node = bc.Child(node_argv(refine, interval, package_dir), env, f'{tag}-node', log_dir=log_dir)
    pub = bc.Child([bc.PY, __file__, 'pub', '--frame', str(FRAME_CACHE)], env, f'{tag}-pub', stdin=True,
                   log_dir=log_dir)
    pub.wait_line('READY', 90)

    def absorb(line):
        if line.startswith('R '):
            _, stamp, recv, _n = line.split()
            images[int(stamp)] = int(recv)
        elif line.startswith('I '):
            _, stamp, fx, _finite, recv = line.split()
            infos[int(stamp)] = (float(fx), int(recv))

    def sink(line, into=sent):
        if line.startswith('S '):
            into.append(int(line[2:]))
    try:
        for _ in range(3):  # warm-up: QoS matching, maps built, frames flowing
            pub.send('RUN 10 1.5')
            pub.wait_line('DONE', 60, sink=lambda line: sink(line, warm_sent))
        time.sleep(1.0)
        if paused:
            for c in children(node.pid):
                os.kill(c, signal.SIGSTOP)
        sub.drain(absorb)
        images.clear()
        warm_infos.update(infos)
        infos.clear()
        cpu0 = node_cpu_seconds(node.pid)
        worker0 = {c: node_cpu_seconds(c) or 0.0 for c in children(node.pid)}
        worker = dict(worker0)
        pub.send(f'RUN {rate} {seconds}')
        done = None
        while done is None:  # the worker's CPU sampled while it lives (it exits once refined)
            try:
                done = pub.wait_line('DONE', 0.5, sink=sink)
            except TimeoutError:
                pass
            for c in children(node.pid):
                worker[c] = node_cpu_seconds(c) or worker.get(c, 0.0)
        time.sleep(2.0)
        sub.drain(absorb)
        cpu = node_cpu_seconds(node.pid) - cpu0
        worker_cpu = sum(worker.values()) - sum(worker0.values())
        if paused:
            for c in children(node.pid):
                os.kill(c, signal.SIGCONT)
    finally:
        for child in (pub, node, sub):
            child.stop()
    elapsed = float(done.split()[2])
    got = [s for s in sent if s in images]
    got_info = [s for s in sent if s in infos]
    # adoption over every CameraInfo since the first frame of the warm-up
    every_info = {**warm_infos, **infos}
    seen = [s for s in warm_sent + sent if s in every_info]
    first_sent = (warm_sent or sent)[0]
    fx0 = every_info[seen[0]][0] if seen else float('nan')
    adopted = next((s for s in seen if abs(every_info[s][0] - fx0) > 1e-6), None)
    changes = sum(abs(every_info[a][0] - every_info[b][0]) > 1e-6 for a, b in zip(seen, seen[1:]))
    gaps = np.diff(sorted(images[s] for s in got)) * 1e-6 if len(got) > 1 else np.array([float('nan')])
    log = (log_dir / f'{tag}-node.stderr.log').read_text() if (log_dir / f'{tag}-node.stderr.log').exists() else ''
    return {'refine': refine, 'sent': len(sent), 'offered_fps': len(sent) / elapsed, 'rect': len(got),
            'info': len(got_info), 'lost_rect': len(sent) - len(got), 'lost_info': len(sent) - len(got_info),
            'max_gap_ms': float(np.max(gaps)), 'adopted_s': (adopted - first_sent) * 1e-9 if adopted else None,
            'fx': (fx0, every_info[adopted][0]) if adopted else (fx0, None), 'adoptions': int(changes),
            'node_cpu_s': cpu, 'worker_cpu_s': worker_cpu,
            'log_lines': [line for line in log.splitlines() if 'refine' in line][:8]}


def node_cpu_seconds(pid: int):
    """CPU seconds (user + system) the node process (not its worker) used so far."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return None


def children(pid: int):
    out = []
    for task in Path(f'/proc/{pid}/task').glob('*'):
        try:
            out += [int(c) for c in (task / 'children').read_text().split()]
        except (OSError, ValueError):
            pass
    return out


def uptime() -> str:
    return subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()


def main():
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('role', nargs='?', default='bench', choices=['bench', 'pub'])
    p.add_argument('--frame', help='pub: the .npy frame')
    p.add_argument('--seconds', type=float, default=45.0, help='streaming seconds per case')
    p.add_argument('--rate', type=float, default=30.0)
    p.add_argument('--interval', type=float, default=2.0, help='refine_interval')
    p.add_argument('--rounds', type=int, default=2)
    p.add_argument('--cases', default='off,on',
                   help='comma-separated, alternated per round: off, on, paused (refine on, worker stopped)')
    p.add_argument('--package-dir', help='run the node from this source tree instead of install/')
    p.add_argument('--write', action='store_true', help=f'write {RESULT.relative_to(bc.REPO)}')
    args = p.parse_args()
    if args.role == 'pub':
        return run_pub(args)
    bc.install_signal_handlers()
    frame()
    before = uptime()
    log_dir = Path(tempfile.mkdtemp(prefix='refine_node_bench_'))
    results = []
    cases = [c.strip() for c in args.cases.split(',') if c.strip()]
    for r in range(args.rounds):
        for case in (cases if r % 2 == 0 else cases[::-1]):  # the order alternates: load drifts
            load = Path('/proc/loadavg').read_text().split()[0]
            tag = f'r{r}-{case}'
            res = run_case(case != 'off', args.seconds, args.rate, args.interval, log_dir, args.package_dir, tag,
                           paused=case == 'paused')
            res['case'], res['round'], res['load'] = case, r + 1, load
            results.append(res)
            print(tag, {k: v for k, v in res.items() if k != 'log_lines'}, flush=True)
    after = uptime()
    rows = ['| case | load at start | sent | offered fps | image_rect lost | camera_info lost | longest gap ms | '
            'node CPU s | worker CPU s | refined CameraInfo after |', '|---|---|---|---|---|---|---|---|---|---|']
    for i, res in enumerate(results):
        adopted = (f"{res['adopted_s']:.1f} s (fx {res['fx'][0]:.1f} -> {res['fx'][1]:.1f}); "
                   f"{res['adoptions']} calibration(s) adopted in the run") \
            if res['adopted_s'] is not None else ('-' if res['case'] != 'on' else 'not within the run')
        label = {'off': 'refine off', 'on': 'refine on', 'paused': 'refine on, worker paused'}[res['case']]
        rows.append(f"| round {res['round']}, {label} | {res['load']} | {res['sent']} | "
                    f"{res['offered_fps']:.1f} | {res['lost_rect']} | {res['lost_info']} | {res['max_gap_ms']:.0f} | "
                    f"{res['node_cpu_s']:.1f} | {res['worker_cpu_s']:.1f} | {adopted} |")
    lost = {k: sum(r['lost_rect'] for r in results if r['case'] == k) for k in cases}
    sent = {k: sum(r['sent'] for r in results if r['case'] == k) for k in cases}
    command = ' '.join(['.venv/bin/python', 'benchmarks/refine_node.py'] + sys.argv[1:])
    text = '\n'.join([
        '# The node with refine at 30 fps 1080p (benchmarks/refine_node.py)', '',
        f'Command: `{command}`', '',
        f'`uptime` before: `{before}`  ', f'`uptime` after: `{after}`', '',
        f'{bc.versions()}; {os.cpu_count()} CPUs (shared with other jobs: cases alternate, off / on).', '',
        'Stream: one 1920x1080 bgr8 frame rendered through a known wide camera (test/scenes.py room), '
        f'{args.rate:g} fps best effort for {args.seconds:g} s per case; node with rectify:=true, '
        f'refine_interval {args.interval:g} s, after a warm-up of 3 x 1.5 s at 10 fps; lost = frames of the '
        'measured stream whose image_rect / CameraInfo never arrived; the refined CameraInfo is timed from '
        'the first frame of the warm-up.', '',
        *rows, '',
        'Total image_rect lost: ' + ', '.join(f'{k} {lost[k]} of {sent[k]}' for k in cases) + '.',
        '', 'Node log (refine lines, last case with refine on):', '',
        '```', *next((r['log_lines'] for r in reversed(results) if r['case'] == 'on'), []), '```', ''])
    print(text)
    if args.write:
        RESULT.write_text(text)
        print(f'wrote {RESULT}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
