#!/usr/bin/env python3
"""Start-up, map rebuild on a parameter change, and memory of the node, at 1080p and 4K.

* start-up: from the node's process start to the first CameraInfo received by another process
  (a late-joiner subscription: reliable, transient local), and to the first image_rect while a
  30 fps publisher waits for the node;
* parameter change while 30 fps frames stream (hfov 118 -> 122 -> 118): the set_parameters
  round trip, the node's own map build time (its log), the time until the subscriber gets the
  first frame of the new calibration, the longest gap between image_rect frames around the
  change and the frames dropped there;
* memory: VmRSS after start-up, peak VmHWM while rectifying 30 fps, and its split (RssAnon:
  heap, RssFile: libraries, RssShmem: the Fast DDS shared-memory segments).

    .venv/bin/python benchmarks/startup_and_memory.py
    .venv/bin/python benchmarks/startup_and_memory.py --baseline HEAD   # also the node of a git ref

``--baseline REF`` also measures the zeroshot_calib_ros package as committed at REF (exported
read-only with ``git archive`` into a temporary directory) for a before/after comparison.
rectify_throughput.py runs this too. Every child process is stopped, bounded in time.
"""
from __future__ import annotations

import argparse
import io
import json
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_common as bc  # noqa: E402

COMMON = bc.BENCH / 'bench_common.py'


def node_argv(width, height, rectify=True, package_dir=None):
    params = {'width': width, 'height': height, 'hfov': bc.HFOV, 'vfov': bc.vfov_for(width, height),
              'rectify': 'true' if rectify else 'false'}
    args = ['--ros-args']
    for k, v in params.items():
        args += ['-p', f'{k}:={v}']
    if package_dir is None:
        return [bc.NODE_EXECUTABLE, *args]
    code = (f'import sys; sys.path.insert(0, {str(package_dir)!r}); '
            'from zeroshot_calib_ros.ros.node import main; sys.exit(main())')
    return [bc.PY, '-c', code, *args]


def export_ref(ref: str) -> Path:
    """The zeroshot_calib_ros package as committed at ``ref``, in a temporary directory."""
    data = subprocess.run(['git', '-C', str(bc.REPO), 'archive', '--format=tar', ref, 'zeroshot_calib_ros'],
                          capture_output=True, check=True).stdout
    target = Path(tempfile.mkdtemp(prefix=f'zeroshot_{re.sub(r"[^A-Za-z0-9]", "_", ref)}_'))
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(target)
    return target


def _absorb_into(images, infos, setdone):
    def absorb(line):
        if line.startswith('R '):
            _, stamp, recv, _n = line.split()
            images.append((int(stamp), int(recv)))
        elif line.startswith('I '):
            _, stamp, fx, finite, recv = line.split()
            infos.append((int(stamp), float(fx), finite == '1', int(recv)))
        elif line.startswith('SETDONE'):
            setdone.append(line.split(None, 6))
    return absorb


def start_up(width, height, log_dir, package_dir=None, label='node'):
    """Seconds from the node's process start to its first CameraInfo / first image_rect."""
    env = bc.ros_env(bc.next_domain())
    tag = f'startup-{label}-{width}x{height}'
    sub = bc.Child([bc.PY, COMMON, 'sub', '--topic', 'image_rect', '--info-topic', 'camera_info', '--info-latched'],
                   env, f'{tag}-sub', stdin=True, log_dir=log_dir)
    pub = None
    node = None
    images, infos, setdone = [], [], []
    try:
        sub.wait_line('READY', 60)
        pub = bc.Child([bc.PY, COMMON, 'pub', '--width', width, '--height', height, '--encoding', 'bgr8',
                        '--match-timeout', '60'], env, f'{tag}-pub', stdin=True, log_dir=log_dir)
        time.sleep(2.0)  # the publisher process is up and waiting for the node
        t0 = time.time_ns()
        node = bc.Child(node_argv(width, height, package_dir=package_dir), env, f'{tag}-node', log_dir=log_dir)
        pub.wait_line('READY', 60)
        pub.send('RUN 30 8')
        absorb = _absorb_into(images, infos, setdone)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not (images and infos):
            sub.drain(absorb)
            time.sleep(0.02)
        first_info = (min(i[3] for i in infos) - t0) * 1e-9 if infos else float('nan')
        first_rect = (min(r[1] for r in images) - t0) * 1e-9 if images else float('nan')
        return {'first_camera_info_s': first_info, 'first_image_rect_s': first_rect}
    finally:
        for child in (pub, node, sub):
            if child is not None:
                child.stop()


def rebuild_and_memory(width, height, log_dir, quick, package_dir=None, label='node'):
    """Parameter changes during a 30 fps stream; RSS of the node."""
    env = bc.ros_env(bc.next_domain())
    tag = f'rebuild-{label}-{width}x{height}'
    images, infos, setdone = [], [], []
    absorb = _absorb_into(images, infos, setdone)
    sub = bc.Child([bc.PY, COMMON, 'sub', '--topic', 'image_rect', '--info-topic', 'camera_info'],
                   env, f'{tag}-sub', stdin=True, log_dir=log_dir)
    sub.wait_line('READY', 60)
    node = bc.Child(node_argv(width, height, package_dir=package_dir), env, f'{tag}-node', log_dir=log_dir)
    pub = bc.Child([bc.PY, COMMON, 'pub', '--width', width, '--height', height, '--encoding', 'bgr8'],
                   env, f'{tag}-pub', stdin=True, log_dir=log_dir)
    changes = [122.0, 118.0] if quick else [122.0, 118.0, 125.0, 118.0]
    spacing = 4.0
    rate = stream_rate(width, height)
    try:
        pub.wait_line('READY', 90)
        pub.send('RUN 10 3')  # warm-up: the node matches the best-effort publisher
        pub.wait_line('DONE', 60)
        time.sleep(1.0)
        idle = bc.proc_status(node.pid)
        seconds = spacing * (len(changes) + 1)
        pub.send(f'RUN {rate} {seconds}')
        t_start = time.monotonic()
        sent_at = []
        for i, hfov in enumerate(changes):
            while time.monotonic() < t_start + spacing * (i + 1):
                sub.drain(absorb)
                time.sleep(0.02)
            sent_at.append(time.time_ns())
            sub.send(f'SET hfov {hfov!r}')
        pub.wait_line('DONE', seconds + 60)
        time.sleep(1.0)
        sub.drain(absorb)
        streaming = bc.proc_status(node.pid)
        log = Path(log_dir, f'{tag}-node.stderr.log').read_text() if log_dir else ''
    finally:
        for child in (pub, node, sub):
            child.stop()
    builds = [float(m) for m in re.findall(r'maps of generation \d+ built in (\d+) ms', log)]
    info_by_stamp = {s: fx for s, fx, _, _ in infos}
    frames = sorted((recv, info_by_stamp.get(stamp)) for stamp, recv in images)
    results = []
    for i, t_req in enumerate(sent_at):
        done = next((d for d in setdone if int(d[2]) >= t_req - 1), None)
        previous_fx = next((fx for recv, fx in reversed(frames) if recv < t_req and fx is not None), None)
        new = next((recv for recv, fx in frames if recv > t_req and fx is not None and previous_fx is not None
                    and abs(fx - previous_fx) > 1e-6), None)
        window = [recv for recv, _ in frames if t_req - 1e9 <= recv <= t_req + 3e9]
        gaps = np.diff(window) * 1e-6 if len(window) > 1 else np.array([float('nan')])
        expected = 4.0 * rate
        results.append({'hfov': changes[i], 'rate': rate,
                        'set_parameters_ms': (int(done[3]) - int(done[2])) * 1e-6 if done else float('nan'),
                        'successful': bool(done and done[4] == '1'),
                        'new_calibration_at_subscriber_ms': (new - t_req) * 1e-6 if new else float('nan'),
                        'max_gap_ms': float(np.nanmax(gaps)),
                        'frames_in_4s_window': len(window), 'expected_in_window': expected})
    return {'changes': results, 'node_build_ms': builds, 'rss_idle': idle, 'rss_streaming': streaming,
            'non_finite_camera_info': sum(1 for i in infos if not i[2])}


def stream_rate(width, height):
    """Frame rate of the parameter-change stream: 30 fps, 15 at 4K (on 2 cores even the relay
    cannot carry 30 fps of 4K bgr8, so drops there would not be the rebuild's)."""
    return 15 if width * height > 1920 * 1080 else 30


def run_all(sizes=('1920x1080', '3840x2160'), quick=False, log_dir=None, baseline=None):
    log_dir = log_dir or Path(tempfile.mkdtemp(prefix='zeroshot_bench_'))
    Path(log_dir).mkdir(parents=True, exist_ok=True)
    variants = [('node', None)]
    if baseline:
        variants.append((f'baseline {baseline}', export_ref(baseline)))
    out = {'sizes': {}, 'variants': [v[0] for v in variants]}
    repeats = 1 if quick else 3
    for size in sizes:
        w, h = bc.SIZES[size]
        out['sizes'][size] = {}
        for label, package_dir in variants:
            print(f'# start-up / rebuild {label} {size}', file=sys.stderr, flush=True)
            starts = [start_up(w, h, log_dir, package_dir, label.split()[0]) for _ in range(repeats)]
            rebuild = rebuild_and_memory(w, h, log_dir, quick, package_dir, label.split()[0])
            out['sizes'][size][label] = {'start_up': starts, 'rebuild': rebuild}
    return out


def _median(values):
    values = [v for v in values if v == v]
    return float(np.median(values)) if values else float('nan')


def report_lines(res):
    lines = ['## Start-up, map rebuild on a parameter change, memory', '',
             '| frame | node | start -> first CameraInfo s | start -> first image_rect s | '
             'set_parameters round trip ms | map build in the node ms | change -> first new frame ms | '
             'longest frame gap ms | frames in the 4 s around a change (of) | RSS idle MiB | '
             'peak RSS streaming MiB (anon / file / shmem) |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    for size, variants in res['sizes'].items():
        for label, r in variants.items():
            st = r['start_up']
            rb = r['rebuild']
            ch = rb['changes']
            idle, streaming = rb['rss_idle'], rb['rss_streaming']
            lines.append(
                f"| {size} | {label} | {_median([s['first_camera_info_s'] for s in st]):.2f} | "
                f"{_median([s['first_image_rect_s'] for s in st]):.2f} | "
                f"{_median([c['set_parameters_ms'] for c in ch]):.0f} | "
                f"{_median(rb['node_build_ms']) if rb['node_build_ms'] else float('nan'):.0f} | "
                f"{_median([c['new_calibration_at_subscriber_ms'] for c in ch]):.0f} | "
                f"{max(c['max_gap_ms'] for c in ch):.0f} | "
                f"{min(c['frames_in_4s_window'] for c in ch)} ({ch[0]['expected_in_window']:.0f}) | "
                f"{idle.get('VmRSS', float('nan')):.0f} | "
                f"{streaming.get('VmHWM', float('nan')):.0f} ({streaming.get('RssAnon', float('nan')):.0f} / "
                f"{streaming.get('RssFile', float('nan')):.0f} / {streaming.get('RssShmem', float('nan')):.0f}) |")
    lines += ['', 'Start-up: medians of the repeats; the CameraInfo subscriber is a late joiner (reliable, '
              'transient local); a 30 fps bgr8 publisher is waiting for the node. Parameter change: '
              'hfov 118 -> 122 -> 118 -> 125 -> 118 every 4 s while bgr8 frames stream (30 fps; 15 fps at 4K, '
              'which this 2-core machine cannot carry at 30 even through the relay); "change -> first '
              'new frame" is from the set_parameters request to the first image_rect whose CameraInfo '
              'carries the new focal length; the frame gap is the longest interval between image_rect '
              'frames in the 4 s around a change (33 / 67 ms nominal); frames: the fewest received in those '
              '4 s over the changes. Node map build: its own log (baseline: inside set_parameters). RSS from '
              '/proc/<pid>/status; RssShmem is the Fast DDS shared-memory segment pages touched (the '
              "profile's 128 MiB segment).", '']
    return lines


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--quick', action='store_true')
    p.add_argument('--sizes', default='1920x1080,3840x2160')
    p.add_argument('--baseline', default=None, help='git ref whose committed node is measured too')
    p.add_argument('--out', default=str(bc.RESULTS / 'startup_and_memory.md'))
    args = p.parse_args(argv)
    bc.install_signal_handlers()
    if not bc.NODE_EXECUTABLE.exists():
        sys.exit(f'{bc.NODE_EXECUTABLE} is missing: run `make build` first')
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    res = run_all([s for s in args.sizes.split(',') if s], args.quick, None, args.baseline)
    text = '\n'.join([f'# Start-up and memory ({"quick" if args.quick else "full"} run)', '',
                      f'Command: `.venv/bin/python benchmarks/startup_and_memory.py {" ".join(argv or sys.argv[1:])}`',
                      f'Date: {time.strftime("%Y-%m-%d %H:%M:%S %Z")}; {bc.versions()}', '',
                      '```', bc.machine_description(), '```', ''] + report_lines(res))
    print(text)
    out.write_text(text)
    out.with_suffix('.json').write_text(json.dumps(res, indent=1, default=str))
    print(f'written: {out}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
