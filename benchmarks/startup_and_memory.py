#!/usr/bin/env python3
"""Start-up, map rebuild on a parameter change, and memory of the node, at 1080p and 4K.

* start-up: from the node's process start to the first CameraInfo received by another process
  (a late-joiner subscription: reliable, transient local), with rectify on and off, and to the
  first image_rect (rectify on) while a 30 fps publisher waits for the node; and the import time
  of the node module (``zeroshot_calib_ros.ros.node``) in a fresh interpreter, with whether it
  imported scipy.optimize (targets of issue 14: first CameraInfo <= 0.6 s at 1080p with rectify
  off, <= 0.9 s with rectify on);
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
import os
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


# --- a quiet machine: the CPU other processes use ---------------------------------------------
_CLK_TCK = os.sysconf('SC_CLK_TCK')
QUIET_CPU = 0.3
"""Other processes (outside this benchmark) may use at most this many cores before a measurement."""
DISTURBED_CPU = 0.6
"""A measurement during which other processes used more cores than this is repeated."""
WAIT_BUDGET_S = [3600.0]
"""What all the waits for a quiet machine of one run may take together (then measurements go on
as the machine is, and the results say how busy it was)."""


def _process_table():
    """{pid: (ppid, ticks)}, ticks = utime + stime + cutime + cstime (reaped children included)."""
    table = {}
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open(f'/proc/{entry}/stat') as f:
                fields = f.read().rpartition(')')[2].split()
        except OSError:
            continue
        table[int(entry)] = (int(fields[1]), sum(int(x) for x in fields[11:15]))
    return table


def _busy_ticks():
    with open('/proc/stat') as f:
        user, nice, system, idle, iowait, irq, softirq, steal = map(int, f.readline().split()[1:9])
    return user + nice + system + irq + softirq + steal


def _own_ticks(table, root=None):
    """CPU ticks of this process and its descendants (alive, or reaped into a parent's count)."""
    root = os.getpid() if root is None else root
    children = {}
    for pid, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    total, stack = 0, [root]
    while stack:
        pid = stack.pop()
        if pid in table:
            total += table[pid][1]
        stack.extend(children.get(pid, ()))
    return total


class OtherCpu:
    """Cores used by processes outside this benchmark's process tree since ``start()``."""

    def __init__(self):
        self.start()

    def start(self):
        self._t, self._busy, self._own = time.monotonic(), _busy_ticks(), _own_ticks(_process_table())
        return self

    def cores(self) -> float:
        t, busy, own = time.monotonic(), _busy_ticks(), _own_ticks(_process_table())
        return max(0.0, ((busy - self._busy) - (own - self._own)) / _CLK_TCK / max(1e-3, t - self._t))


def wait_quiet(max_cpu=QUIET_CPU, window=3.0, max_wait=900.0, what='measurement') -> dict:
    """Wait until other processes use less than ``max_cpu`` cores (over ``window`` s), at most
    ``max_wait`` s; returns what was seen (the 1-min load average includes this benchmark's own
    processes, so it is reported, not waited for)."""
    t0 = time.monotonic()
    max_wait = min(max_wait, WAIT_BUDGET_S[0])
    while True:
        meter = OtherCpu()
        time.sleep(window)
        cores = meter.cores()
        waited = time.monotonic() - t0
        if cores < max_cpu or waited >= max_wait:
            WAIT_BUDGET_S[0] = max(0.0, WAIT_BUDGET_S[0] - max(0.0, waited - window))
            if waited > window + 1:
                print(f'#   waited {waited:.0f} s for a quiet machine before the {what} (others: {cores:.2f} cores)',
                      file=sys.stderr, flush=True)
            return {'others_cores_before': cores, 'waited_s': waited, 'quiet': cores < max_cpu,
                    'load1': float(open('/proc/loadavg').read().split()[0])}
        time.sleep(10)


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


def start_up(width, height, log_dir, package_dir=None, label='node', rectify=True):
    """Seconds from the node's process start to its first CameraInfo / first image_rect (nan
    with rectify off)."""
    env = bc.ros_env(bc.next_domain())
    tag = f'startup-{label}-{width}x{height}-rectify-{"on" if rectify else "off"}'
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
        node = bc.Child(node_argv(width, height, rectify=rectify, package_dir=package_dir), env, f'{tag}-node',
                        log_dir=log_dir)
        pub.wait_line('READY', 60)
        pub.send('RUN 30 8')
        absorb = _absorb_into(images, infos, setdone)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not ((images or not rectify) and infos):
            sub.drain(absorb)
            time.sleep(0.02)
        first_info = (min(i[3] for i in infos) - t0) * 1e-9 if infos else float('nan')
        first_rect = (min(r[1] for r in images) - t0) * 1e-9 if images else float('nan')
        return {'first_camera_info_s': first_info, 'first_image_rect_s': first_rect}
    finally:
        for child in (pub, node, sub):
            if child is not None:
                child.stop()


IMPORT_CODE = """import sys, time
{path}t0 = time.perf_counter()
import zeroshot_calib_ros.ros.node
print(time.perf_counter() - t0, int('scipy.optimize' in sys.modules))
"""


def import_time(package_dir=None, repeats=5):
    """Median seconds to import the node module in a fresh interpreter (the ROS environment of
    the benchmarks), and whether that imported scipy.optimize."""
    env = bc.ros_env(bc.next_domain())
    path = f'sys.path.insert(0, {str(package_dir)!r})\n' if package_dir is not None else ''
    times, scipy_optimize = [], set()
    for _ in range(repeats):
        done = subprocess.run([bc.PY, '-c', IMPORT_CODE.format(path=path)], env=env, capture_output=True,
                              text=True, timeout=120, cwd='/')
        seconds, imported = done.stdout.split()
        times.append(float(seconds))
        scipy_optimize.add(imported == '1')
    return {'import_s': float(np.median(times)), 'import_s_all': times,
            'imports_scipy_optimize': any(scipy_optimize)}


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
            print(f'# start-up / rebuild {label} {size} (load {open("/proc/loadavg").read().split()[0]})',
                  file=sys.stderr, flush=True)
            starts = [quietly(start_up, w, h, log_dir, package_dir, label.split()[0]) for _ in range(repeats)]
            starts_off = [quietly(start_up, w, h, log_dir, package_dir, label.split()[0], rectify=False)
                          for _ in range(repeats)]
            rebuild = quietly(rebuild_and_memory, w, h, log_dir, quick, package_dir, label.split()[0])
            out['sizes'][size][label] = {'start_up': starts, 'start_up_rectify_off': starts_off,
                                         'rebuild': rebuild}
    wait_quiet(what='import timing')
    out['import'] = {label: import_time(package_dir, 3 if quick else 7) for label, package_dir in variants}
    return out


ATTEMPTS = [3]
"""Measurements of one figure at most while other processes disturb it (--attempts)."""


def quietly(measure, *args, attempts=None, **kwargs) -> dict:
    """``measure(*args, **kwargs)`` (a dict) on a quiet machine, repeated (at most ``attempts``
    times) while other processes used more than DISTURBED_CPU cores during it; the CPU they used
    is added to the result."""
    attempts = ATTEMPTS[0] if attempts is None else attempts
    for attempt in range(1, attempts + 1):
        quiet = wait_quiet(what=getattr(measure, '__name__', 'measurement'))
        meter = OtherCpu()
        result = measure(*args, **kwargs)
        others = meter.cores()
        result.update(quiet, others_cores=others, attempt=attempt)
        if others <= DISTURBED_CPU or attempt == attempts:
            return result
        print(f'#   other processes used {others:.2f} cores during it: measured again', file=sys.stderr, flush=True)
    return result


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
    lines += startup_target_lines(res)
    return lines


def startup_target_lines(res):
    """Issue 14's start-up figures: first CameraInfo with rectify off and on, import time."""
    lines = ['### Start-up targets (issue 14): first CameraInfo <= 0.6 s (rectify off), <= 0.9 s (rectify on), '
             'at 1080p', '',
             '| frame | node | first CameraInfo s, rectify off (each run) | first CameraInfo s, rectify on (each run) | '
             'import of the node module s | scipy.optimize imported |', '|---|---|---|---|---|---|']
    imports = res.get('import', {})
    for size, variants in res['sizes'].items():
        for label, r in variants.items():
            on = [s['first_camera_info_s'] for s in r['start_up']]
            off = [s['first_camera_info_s'] for s in r.get('start_up_rectify_off', [])]
            imp = imports.get(label)
            lines.append(f"| {size} | {label} | {_median(off):.2f} ({', '.join(f'{v:.2f}' for v in off)}) | "
                         f"{_median(on):.2f} ({', '.join(f'{v:.2f}' for v in on)}) | "
                         f"{imp['import_s']:.2f} | {'yes' if imp['imports_scipy_optimize'] else 'no'} |"
                         if imp else f"| {size} | {label} | {_median(off):.2f} | {_median(on):.2f} | n/a | n/a |")
    runs = [x for variants in res['sizes'].values() for r in variants.values()
            for x in r['start_up'] + r.get('start_up_rectify_off', []) + [r['rebuild']]]
    others = [x['others_cores'] for x in runs if 'others_cores' in x]
    loads = [x['load1'] for x in runs if 'load1' in x]
    lines += ['', 'From the node process\'s start (Popen) to the first CameraInfo received by a late-joiner '
              'subscriber in another process; medians of the runs. Import: `import zeroshot_calib_ros.ros.node` '
              'in a fresh interpreter, median of the runs.' + (
                  (f' Each measurement waited (at most {res.get("quiet_budget_min", 30):g} min over the run) until '
                   f'processes outside the benchmark used < {QUIET_CPU:g} cores' if res.get('quiet_budget_min', 30) > 0
                   else ' Measurements did not wait for a quiet machine (--quiet-budget 0)') +
                  (' and each was measured once (--attempts 1)' if res.get('attempts', 3) == 1 else
                   f' and was measured again (at most {res.get("attempts", 3)} times) if they used more than '
                   f'{DISTURBED_CPU:g} cores') +
                  f'; 1-min load average at the start: median {float(np.median(loads)):.2f}, max {max(loads):.2f}; '
                  f'CPU of other processes during them: median {float(np.median(others)):.2f}, max '
                  f'{max(others):.2f} cores of 2.' if others and loads else ''), '']
    return lines


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--quick', action='store_true')
    p.add_argument('--sizes', default='1920x1080,3840x2160')
    p.add_argument('--baseline', default=None, help='git ref whose committed node is measured too')
    p.add_argument('--out', default=str(bc.RESULTS / 'startup_and_memory.md'))
    p.add_argument('--quiet-budget', type=float, default=30.0,
                   help='minutes all waits for a quiet machine may take together (0: never wait)')
    p.add_argument('--attempts', type=int, default=3, help='measurements of a figure at most while other '
                   'processes used more than 0.6 cores during it (default 3; 1: as the machine is)')
    args = p.parse_args(argv)
    WAIT_BUDGET_S[0] = args.quiet_budget * 60
    ATTEMPTS[0] = args.attempts
    uptime = subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()
    bc.install_signal_handlers()
    if not bc.NODE_EXECUTABLE.exists():
        sys.exit(f'{bc.NODE_EXECUTABLE} is missing: run `make build` first')
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    res = run_all([s for s in args.sizes.split(',') if s], args.quick, None, args.baseline)
    res.update(quiet_budget_min=args.quiet_budget, attempts=args.attempts)
    text = '\n'.join([f'# Start-up and memory ({"quick" if args.quick else "full"} run)', '',
                      f'Command: `.venv/bin/python benchmarks/startup_and_memory.py {" ".join(argv or sys.argv[1:])}`',
                      f'Date: {time.strftime("%Y-%m-%d %H:%M:%S %Z")}; {bc.versions()}',
                      f'`uptime` before the run: {uptime}', '',
                      '```', bc.machine_description(), '```', ''] + report_lines(res))
    print(text)
    out.write_text(text)
    out.with_suffix('.json').write_text(json.dumps(res, indent=1, default=str))
    print(f'written: {out}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
