#!/usr/bin/env python3
"""Rectification at camera rate: the node against the two floors it cannot beat, in one run.

For each frame size (640x480 ... 3840x2160) and encoding (bgr8, mono8), three processes on this
machine: a publisher (best effort, as camera drivers publish) -> the system under test -> a
subscriber, through the project's shared-memory Fast DDS profile:

* node: the installed zeroshot_calib node (``ros2 run zeroshot_calib_ros node``), rectify:=true,
  on its serialized frame path (image_raw taken as CDR bytes, image_rect published as bytes);
* baseline (``--baseline``, default ``message``): the previous node in the same run, i.e. the same
  installed node forced onto its message path (ZEROSHOT_CALIB_FRAME_PATH=message: every frame
  deserialised into a sensor_msgs/Image and serialised back, as before issue 14), or with
  ``--baseline REF`` the package as committed at a git ref; ``--baseline none``: not measured;
* relay: benchmarks/relay_node.py, the same process layout and QoS, republishing each frame
  unchanged (its raw mode: no deserialisation) -- the transport floor;
* remap: ``cv2.remap`` alone on the node's maps, in this process -- the compute floor;
* remap relay (on by default; ``--no-remap-relay``): relay_node.py ``--mode remap``, the raw
  relay that also does what the node must per frame and nothing more -- the node's CameraInfo
  (a template, stamp patched), then ``Rectifier.rectify`` on the node's maps, with the node's
  QoS -- the floor of this node in a stream, where the remap runs on cores that sat idle since
  the last frame (slower than back to back). ``node - remap relay`` is what the node's own work
  costs (frame checks, calibration lookups, counters, its executor's other entities).

* node variants (``--executors``, ``--no-subscriber``): the node spun by rclpy's EventsExecutor
  (ZEROSHOT_CALIB_EXECUTOR=events: ``node_events``), and the node (and the baseline) with no
  image_rect subscriber (``node_nosub``, ``node_events_nosub``, ``baseline_nosub``): the
  subscriber process then takes camera_info only, which is what "received" and latency measure.

Measured per case: latency (publisher stamp -> subscriber receive, wall clock) at 30 fps and the
frames dropped there; the CPU each process under test (node, relay, remap relay) used per frame
at 30 fps (user + system time from /proc/PID/stat over the phase, divided by the frames sent); the
maximum sustained rate (highest offered rate with <= 1 % loss, found by bisection after a
saturation run); the node's peak RSS. Targets (issues #6, #14), evaluated at every size and
reported for 1080p:

    median latency(node)   <= median latency(relay) + remap + 1 ms
    max sustained rate(node) >= 0.9 / (1 / rate(relay) + remap)
    max sustained rate(node) >= 1.15 x max sustained rate(baseline)   (1080p bgr8 and mono8)

and beside them the same two figures of the remap relay, which meets them only if a remap in the
stream is as fast as a back-to-back one. Cost per frame (with ``--no-subscriber``):

    CPU per frame(node, image_rect subscribed) <= 1.1 x CPU per frame(remap relay)
    CPU per frame(node, no image_rect subscriber) <= 1.2 x CPU per frame(relay)

Start the full run on a quiet machine: the 1-min load average (``uptime``) at the start and
before every case is in the results.

Then, in this process, our exact fixed-point maps against OpenCV's fisheye route (what
image_proc does: cv2.fisheye.initUndistortRectifyMap + remap) and cv2.fisheye.undistortImage per
frame: speed and pixel differences; and start-up / map-rebuild / memory figures
(benchmarks/startup_and_memory.py).

    .venv/bin/python benchmarks/rectify_throughput.py            # full run, baseline: message path
    .venv/bin/python benchmarks/rectify_throughput.py --quick    # short run (~5 min)
    .venv/bin/python benchmarks/rectify_throughput.py --sizes 1920x1080 --encodings bgr8 --profile
    .venv/bin/python benchmarks/rectify_throughput.py --sizes 1920x1080 --executors single,events \
        --no-subscriber --baseline 1e01175 --skip compare,startup        # cost per frame

Prints a markdown report and writes it to benchmarks/results/rectify_throughput.md (raw numbers
next to it as .json). Needs the package built (``make build``). Every child process is stopped,
bounded in time, when the script exits.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

# The remap floor is measured in this process with the OpenCV thread-pool settings the node uses
# (zeroshot_calib_ros/ros/node.py sets these before OpenCV loads).
for _name in ('OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER', 'OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN'):
    os.environ.setdefault(_name, '0')

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_common as bc  # noqa: E402
import startup_and_memory as sm  # noqa: E402

sys.path.insert(0, str(bc.site_packages()))

COMMON = bc.BENCH / 'bench_common.py'
LOSS_OK = 0.01  # a rate is sustained when at most 1 % of its frames are lost


class Phase:
    """What one publishing phase sent and what came out."""

    def __init__(self, name, rate, seconds, sent, elapsed, received, infos):
        self.name, self.rate, self.seconds = name, rate, seconds
        self.sent = sent  # stamps (ns)
        self.elapsed = elapsed
        self.received = {s: received[s] for s in sent if s in received}  # stamp -> receive ns
        self.infos = {s: infos[s] for s in sent if s in infos}

    @property
    def lost(self):
        return len(self.sent) - len(self.received)

    @property
    def loss(self):
        return self.lost / max(1, len(self.sent))

    @property
    def offered_rate(self):
        return len(self.sent) / self.elapsed if self.elapsed > 0 else float('nan')

    @property
    def output_rate(self):
        if len(self.received) < 2:
            return 0.0
        times = sorted(self.received.values())
        return (len(times) - 1) / ((times[-1] - times[0]) * 1e-9)

    def latencies_ms(self):
        return np.array([(r - s) * 1e-6 for s, r in self.received.items()])

    def summary(self):
        lat = self.latencies_ms()
        return {'name': self.name, 'requested_rate': self.rate, 'offered_rate': self.offered_rate,
                'sent': len(self.sent), 'received': len(self.received), 'lost': self.lost,
                'output_rate': self.output_rate,
                'latency_ms': {q: bc.percentile(lat, q) for q in (50, 90, 99)} | {
                    'max': float(lat.max()) if len(lat) else float('nan')}}


class Session:
    """publisher -> target -> subscriber in a fresh ROS domain."""

    def __init__(self, system, width, height, encoding, log_dir, node_params=(), relay_mode='raw',
                 info=True, target_env=None, package_dir=None, rect_subscriber=True, executor='single',
                 tag=None):
        self.system, self.width, self.height, self.encoding = system, width, height, encoding
        self.tag = f'{tag or system}-{width}x{height}-{encoding}'
        self.env = bc.ros_env(bc.next_domain())
        self.images, self.infos, self.setdone = {}, {}, []
        self.rss = []
        # without an image_rect subscriber, the frames that come out are the CameraInfo messages
        self.rect_subscriber = rect_subscriber
        sub_argv = [bc.PY, COMMON, 'sub', '--topic', 'image_rect' if rect_subscriber else 'none']
        if system in ('node', 'remap_relay') and (info or not rect_subscriber):
            sub_argv += ['--info-topic', 'camera_info']
        self.sub = bc.Child(sub_argv, self.env, f'{self.tag}-sub', stdin=True, log_dir=log_dir)
        self.sub.wait_line('READY', 60)
        if system == 'node':
            params = {'width': width, 'height': height, 'hfov': bc.HFOV, 'vfov': bc.vfov_for(width, height),
                      'rectify': True, **dict(node_params)}
            argv = [bc.NODE_EXECUTABLE, '--ros-args']
            if package_dir is not None:  # the package of another git ref (--baseline)
                code = (f'import sys; sys.path.insert(0, {str(package_dir)!r}); '
                        'from zeroshot_calib_ros.ros.node import main; sys.exit(main())')
                argv = [bc.PY, '-c', code, '--ros-args']
            for k, v in params.items():
                argv += ['-p', f'{k}:={str(v).lower() if isinstance(v, bool) else v}']
        elif system == 'remap_relay':
            argv = [bc.PY, bc.RELAY, '--mode', 'remap', '--width', width, '--height', height, '--executor', executor]
        else:
            argv = [bc.PY, bc.RELAY, '--mode', relay_mode, '--executor', executor]
        env = {**self.env, **(target_env or {})}
        if system == 'node':
            env['ZEROSHOT_CALIB_EXECUTOR'] = executor
        self.target = bc.Child(argv, env, f'{self.tag}-target', log_dir=log_dir)
        self.pub = bc.Child([bc.PY, COMMON, 'pub', '--width', width, '--height', height, '--encoding', encoding],
                            self.env, f'{self.tag}-pub', stdin=True, log_dir=log_dir)
        self.pub.wait_line('READY', 90)
        self._sampling = True
        self._sampler = threading.Thread(target=self._sample_rss, daemon=True)
        self._sampler.start()

    def _sample_rss(self):
        t0 = time.monotonic()
        while self._sampling:
            st = bc.proc_status(self.target.pid)
            if st:
                self.rss.append((time.monotonic() - t0, st.get('VmRSS', 0.0), st.get('VmHWM', 0.0)))
            time.sleep(0.25)

    def _absorb(self, line):
        if line.startswith('R '):
            _, stamp, recv, _n = line.split()
            self.images[int(stamp)] = int(recv)
        elif line.startswith('I '):
            _, stamp, fx, finite, recv = line.split()
            self.infos[int(stamp)] = (float(fx), finite == '1', int(recv))
            if not self.rect_subscriber:
                self.images[int(stamp)] = int(recv)
        elif line.startswith('SETDONE'):
            self.setdone.append(line.split(None, 6))

    def pull(self):
        self.sub.drain(self._absorb)

    def phase(self, name, rate, seconds, settle=0.6, during=None):
        """Publish at ``rate`` (0: back to back) for ``seconds``; ``during(session)`` is called once
        the phase runs (e.g. to change a parameter)."""
        sent = []
        self.pub.send(f'RUN {rate} {seconds}')
        if during is not None:
            during(self)

        def sink(line):
            if line.startswith('S '):
                sent.append(int(line[2:]))

        done = self.pub.wait_line('DONE', seconds * 3 + 60, sink=sink)
        elapsed = float(done.split()[2])
        # settle: until nothing new arrived for `settle` s (at most 5 s)
        deadline = time.monotonic() + 5.0
        last_count, last_change = -1, time.monotonic()
        while time.monotonic() < deadline:
            self.pull()
            if len(self.images) != last_count:
                last_count, last_change = len(self.images), time.monotonic()
            elif time.monotonic() - last_change >= settle:
                break
            time.sleep(0.05)
        return Phase(name, rate, seconds, sent, elapsed, self.images, self.infos)

    def warm_up(self):
        """Until frames come out, and at least 3 s: the node matches the best-effort publisher's
        QoS in its 1 s housekeeping, re-creating its endpoints once."""
        for attempt in range(8):
            ph = self.phase('warm-up', 10, 1.5)
            if len(ph.received) >= 5 and attempt >= 1:
                return ph
            if not self.target.alive():
                raise RuntimeError(f'{self.tag}: target exited: ' + ' | '.join(self.target.other[-5:]))
        raise RuntimeError(f'{self.tag}: no frame came out during warm-up')

    def peak_rss(self):
        st = bc.proc_status(self.target.pid)
        return st.get('VmHWM', max((r[2] for r in self.rss), default=float('nan')))

    def close(self):
        self._sampling = False
        for child in (self.pub, self.target, self.sub):
            child.stop()


def max_sustained_rate(session, saturation_rate, steps, seconds):
    """Highest offered rate with <= 1 % loss: bracket around the saturation output rate, then
    bisect (geometric) ``steps`` times. Returns (rate, phases)."""
    phases = []

    def trial(rate):
        ph = session.phase(f'trial {rate:.1f}', rate, seconds)
        phases.append(ph.summary())
        ok = ph.loss <= LOSS_OK and ph.offered_rate >= 0.95 * rate
        return ok, ph

    start = max(2.0, saturation_rate)
    ok, ph = trial(start)
    lo = hi = None
    best = ph.offered_rate if ok else 0.0
    if ok:
        lo = start
        for _ in range(3):
            r = lo * 1.25
            ok, ph = trial(r)
            if ok:
                lo, best = r, max(best, ph.offered_rate)
            else:
                hi = r
                break
    else:
        hi = start
        r = start
        for _ in range(6):
            r *= 0.8
            ok, ph = trial(r)
            if ok:
                lo, best = r, ph.offered_rate
                break
            hi = r
    if lo is not None and hi is not None:
        for _ in range(steps):
            r = (lo * hi) ** 0.5
            ok, ph = trial(r)
            if ok:
                lo, best = r, max(best, ph.offered_rate)
            else:
                hi = r
    return best, phases


def profile_target(session, seconds, out_path, rate):
    """py-spy on the target while frames stream at ``rate``; returns the collapsed-stack file."""
    spy = Path(bc.PY).parent / 'py-spy'
    if not spy.exists():
        return None, 'py-spy not installed (.venv/bin/pip install py-spy)'
    cmd = [str(spy), 'record', '--pid', str(session.target.pid), '--duration', str(int(seconds)),
           '--rate', '250', '--format', 'raw', '--output', str(out_path), '--nonblocking', '--threads', '--idle']
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(0.5)
    session.phase('profiled', rate, seconds)
    try:
        out, _ = proc.communicate(timeout=seconds + 30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out_path if out_path.exists() else None, out


_FRAME_CALLBACKS = ('_on_image', '_on_serialized_image')
PROFILE_CATEGORIES = [
    # (label, predicate on the ';'-joined main-thread stack), first match wins
    ('cv2.remap (Rectifier.rectify)', lambda st: 'Rectifier.rectify' in st),
    # (_publish_rectified: the message path's; _publish_rectified_serialized: the serialized path's)
    ('publish image_rect (convert, serialise, write)', lambda st: '_publish_rectified' in st and (
        'publish (' in st or 'publish_serialized' in st)),
    ('publish CameraInfo', lambda st: any(f in st for f in _FRAME_CALLBACKS) and (
        'Publisher.publish' in st or 'publish_serialized' in st)),
    ('other Python in the frame callback', lambda st: any(f in st for f in _FRAME_CALLBACKS)),
    ('take image_raw (deserialise into Python)', lambda st: '_take_subscription (' in st),
    ('executor waiting (idle)', lambda st: '_wait_for_ready_callbacks' in st and 'handler' not in st),
    ('other (timers, executor, parameters)', lambda st: True),
]


def summarise_profile(path):
    """Share of the executor thread's samples (py-spy raw, --idle) per category: where a frame's
    time goes. Threads that do not run the executor (the map builder) are left out."""
    counts = collections.Counter()
    total = 0
    for line in Path(path).read_text().splitlines():
        stack, _, count = line.rpartition(' ')
        try:
            n = int(count)
        except ValueError:
            continue
        if 'spin (rclpy' not in stack:
            continue
        total += n
        counts[next(label for label, match in PROFILE_CATEGORIES if match(stack))] += n
    return total, [(label, counts[label]) for label, _ in PROFILE_CATEGORIES]


# --- in-process floors and comparisons ----------------------------------------------------
def timed(fn, repeat, warm=2, pause=0.0):
    """Median ms of ``fn``; with ``pause`` s of sleep before each call (as frames arrive)."""
    for _ in range(warm):
        fn()
    times = []
    for _ in range(repeat):
        if pause:
            time.sleep(pause)
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3


def remap_floor(width, height, encoding, repeat):
    import cv2
    from zeroshot_calib_ros.core.ros_formats import rectify as rectify_module
    active = bc.node_calibration(width, height)
    _, rectifier = active.for_size(width, height)
    image = bc.test_image(width, height, bc.CHANNELS[encoding])
    out = np.empty_like(image)
    threads_before = cv2.getNumThreads()
    node_threads = getattr(rectify_module, 'REMAP_THREADS', None)
    result = {}
    for label, threads in (('1 thread', 1), ('default', threads_before)):
        cv2.setNumThreads(threads)
        result[label] = timed(lambda: rectifier.rectify(image, out=out), repeat)
        # one call per 33 ms, as in a 30 fps stream: idle cores, sleeping OpenCV workers, cold caches
        result[label + ' paced'] = timed(lambda: rectifier.rectify(image, out=out), max(10, repeat // 2),
                                         pause=1 / 30)
    cv2.setNumThreads(threads_before)
    prefix = '1 thread' if node_threads == 1 else 'default'
    result['node'], result['node paced'] = result[prefix], result[prefix + ' paced']
    return result


def compare_with_opencv(width, height, encoding, repeat):
    """Our exact fixed-point maps vs cv2.fisheye maps of the published CameraInfo (image_proc's
    route) vs cv2.fisheye.undistortImage per frame."""
    import cv2
    from zeroshot_calib_ros.core.ros_formats.rectify import Rectifier
    active = bc.node_calibration(width, height)
    cal = active.calibration
    K, D, P = cal.K, cal.D, cal.P[:3, :3]
    image = bc.test_image(width, height, bc.CHANNELS[encoding])
    out_ours, out_cv, out_und = (np.empty_like(image) for _ in range(3))
    build_ours = timed(lambda: Rectifier(active.camera, P=P, interpolation=1), max(1, repeat // 10), warm=0)
    rectifier = Rectifier(active.camera, P=P, interpolation=1)
    build_cv = timed(lambda: cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), P, (width, height),
                                                                 cv2.CV_16SC2), max(1, repeat // 10), warm=1)
    m1, m2 = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), P, (width, height), cv2.CV_16SC2)
    frame_ours = timed(lambda: rectifier.rectify(image, out=out_ours), repeat)
    frame_cv = timed(lambda: cv2.remap(image, m1, m2, cv2.INTER_LINEAR, dst=out_cv,
                                       borderMode=cv2.BORDER_CONSTANT), repeat)
    frame_und = timed(lambda: cv2.fisheye.undistortImage(image, K, D, Knew=P, new_size=(width, height)),
                      max(3, repeat // 4), warm=1)
    out_und[...] = cv2.fisheye.undistortImage(image, K, D, Knew=P, new_size=(width, height))
    # map positions: ours vs OpenCV's float maps, over pixels both see inside the image
    fx, fy = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), P, (width, height), cv2.CV_32FC1)
    ox, oy = cv2.convertMaps(rectifier.map1, rectifier.map2, cv2.CV_32FC1)
    inside = (fx >= 0) & (fx <= width - 1) & (fy >= 0) & (fy <= height - 1) & (ox >= 0) & (oy >= 0)
    map_err = np.hypot(ox - fx, oy - fy)[inside]

    def diff(a, b):
        d = np.abs(a.astype(np.int16) - b.astype(np.int16))
        return {'max': int(d.max()), 'mean': float(d.mean()), 'gt1': float((d > 1).mean())}

    return {'build_ms': {'ours': build_ours, 'cv_maps': build_cv},
            'frame_ms': {'ours': frame_ours, 'cv_maps': frame_cv, 'undistortImage': frame_und},
            'diff_vs_cv_maps': diff(out_ours, out_cv), 'diff_vs_undistortImage': diff(out_ours, out_und),
            'map_err_px': {'max': float(map_err.max()), 'p99': float(np.percentile(map_err, 99)),
                           'mean': float(map_err.mean())},
            'fit_error_px': None}


# --- report -----------------------------------------------------------------------------------
def profile_report(results):
    rows = []
    for r in results:
        for system in ('baseline', 'node'):
            prof = r.get(system, {}).get('profile')
            if prof and Path(prof).exists():
                total, shares = summarise_profile(prof)
                if total:
                    rows.append((f"{r['size']} {r['encoding']}", system, total, shares))
    if not rows:
        return []
    labels = [label for label, _ in PROFILE_CATEGORIES]
    lines = ['### Where the time goes: py-spy of the node\'s executor thread at 90 % of its max rate', '',
             '| frame | node | samples | ' + ' | '.join(labels) + ' |',
             '|---|---|---|' + '---|' * len(labels)]
    for frame, system, total, shares in rows:
        lines.append(f'| {frame} | {system} | {total} | ' +
                     ' | '.join(f'{100 * n / total:.1f} %' for _, n in shares) + ' |')
    lines += ['', 'py-spy record --idle --nonblocking at 250 Hz for the profile phase; shares of the samples of '
              'the thread running rclpy.spin (the map-builder thread, idle while streaming, is left out). '
              'baseline = the node before this change (see above).', '']
    return lines



def fmt(x, digits=1):
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return 'n/a'
    return f'{x:.{digits}f}'


def targets(r) -> tuple:
    """(latency with the hot remap, latency with the paced remap, rate) targets of a case: relay
    p50 + remap + 1 ms, and 0.9 / (1 / relay max fps + hot remap)."""
    relay, remap = r['relay'], r['remap_ms']
    latency = relay['p30']['latency_ms'][50] + 1.0
    rate = 0.9 / (1.0 / relay['max_rate'] + remap['node'] * 1e-3) if relay['max_rate'] > 0 else float('nan')
    return latency + remap['node'], latency + remap['node paced'], rate


def throughput_table(results):
    baseline = any('baseline' in r for r in results)
    lines = ['| frame | enc | remap ms hot / paced | relay p50 ms | node p50 ms | node p99 ms | '
             'target p50 ms (hot / paced remap) | latency met (hot / paced) | relay max fps | node max fps | '
             'target fps | rate met | 30 fps drops node (relay) | node peak RSS MiB |'
             + (' baseline p50 ms / max fps / drops |' if baseline else ''),
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|' + ('---|' if baseline else '')]
    for r in results:
        remap, paced = r['remap_ms']['node'], r['remap_ms']['node paced']
        relay, node = r['relay'], r['node']
        t_lat, t_lat_paced, t_rate = targets(r)
        lat_ok = node['p30']['latency_ms'][50] <= t_lat
        lat_ok_paced = node['p30']['latency_ms'][50] <= t_lat_paced
        rate_ok = node['max_rate'] >= t_rate
        r['targets'] = {'latency_ms': t_lat, 'latency_ms_paced': t_lat_paced, 'rate': t_rate,
                        'latency_met': bool(lat_ok), 'latency_met_paced': bool(lat_ok_paced), 'rate_met': bool(rate_ok)}
        yes = lambda ok: 'yes' if ok else '**no**'  # noqa: E731
        lines.append(
            f"| {r['size']} | {r['encoding']} | {fmt(remap, 2)} / {fmt(paced, 2)} | "
            f"{fmt(relay['p30']['latency_ms'][50], 2)} | "
            f"{fmt(node['p30']['latency_ms'][50], 2)} | {fmt(node['p30']['latency_ms'][99], 2)} | "
            f"{fmt(t_lat, 2)} / {fmt(t_lat_paced, 2)} | {yes(lat_ok)} / {yes(lat_ok_paced)} | "
            f"{fmt(relay['max_rate'])} | {fmt(node['max_rate'])} | "
            f"{fmt(t_rate)} | {'yes' if rate_ok else '**no**'} | "
            f"{node['p30']['lost']}/{node['p30']['sent']} ({relay['p30']['lost']}/{relay['p30']['sent']}) | "
            f"{fmt(node['peak_rss_mib'], 0)} |" + (
                f" {fmt(r['baseline']['p30']['latency_ms'][50], 2)} / {fmt(r['baseline']['max_rate'])} / "
                f"{r['baseline']['p30']['lost']} |" if 'baseline' in r else ''))
    return '\n'.join(lines)


def speedup_lines(results):
    """Max rate of the node against the baseline (the previous node) in the same run, per case."""
    rows = [r for r in results if 'baseline' in r]
    if not rows:
        return []
    lines = ['### The node against the previous node (baseline), same run', '',
             '| frame | enc | baseline max fps | node max fps | node / baseline | baseline p50 ms | node p50 ms | '
             'target >= 1.15x (1080p) |', '|---|---|---|---|---|---|---|---|']
    for r in rows:
        base, node = r['baseline'], r['node']
        ratio = node['max_rate'] / base['max_rate'] if base['max_rate'] > 0 else float('nan')
        target = ('yes' if ratio >= 1.15 else '**no**') if r['size'] == '1920x1080' else ''
        r['speedup'] = ratio
        lines.append(f"| {r['size']} | {r['encoding']} | {fmt(base['max_rate'])} | {fmt(node['max_rate'])} | "
                     f"{fmt(ratio, 2)}x | {fmt(base['p30']['latency_ms'][50], 2)} | "
                     f"{fmt(node['p30']['latency_ms'][50], 2)} | {target} |")
    lines += ['', 'Max fps of each: highest offered rate with <= 1 % loss, median of the rounds; both measured '
              'alternately with the relay, case by case, in this run.', '']
    return lines


def stream_floor_lines(results):
    """The node against the remap relay (the raw relay plus the node's remap, nothing else) in the
    same run: what the node's own work costs, and the targets measured on that floor."""
    rows = [r for r in results if 'remap_relay' in r]
    if not rows:
        return []
    lines = ['### The node against the remap relay (relay + the node\'s remap in the stream), same run', '',
             '| frame | enc | relay p50 ms | remap relay p50 ms | node p50 ms | node - remap relay ms | '
             'remap relay over relay ms | remap hot ms | remap relay latency target met | remap relay max fps | '
             'node max fps | node / remap relay | remap relay rate target met | 30 fps drops remap relay |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        relay, floor, node = r['relay'], r['remap_relay'], r['node']
        remap = r['remap_ms']['node']
        t_lat, _, t_rate = targets(r)
        lat, floor_lat, node_lat = (x['p30']['latency_ms'][50] for x in (relay, floor, node))
        ratio = node['max_rate'] / floor['max_rate'] if floor['max_rate'] > 0 else float('nan')
        yes = lambda ok: 'yes' if ok else '**no**'  # noqa: E731
        lines.append(f"| {r['size']} | {r['encoding']} | {fmt(lat, 2)} | {fmt(floor_lat, 2)} | {fmt(node_lat, 2)} | "
                     f"{node_lat - floor_lat:+.2f} | {floor_lat - lat:.2f} | {fmt(remap, 2)} | "
                     f"{yes(floor_lat <= t_lat)} | {fmt(floor['max_rate'])} | {fmt(node['max_rate'])} | "
                     f"{fmt(ratio, 2)}x | {yes(floor['max_rate'] >= t_rate)} | "
                     f"{floor['p30']['lost']}/{floor['p30']['sent']} |")
    lines += ['', 'Remap relay: `benchmarks/relay_node.py --mode remap`, what the node must do per frame and '
              'nothing more: the node\'s CameraInfo (a serialized template, stamp patched), then '
              '`Rectifier.rectify` on the node\'s maps into a reused serialized buffer, published as bytes, '
              'with the node\'s QoS; no checks, lookups, parameters or diagnostics. Its targets are the node\'s '
              '(relay p50 + hot remap + 1 ms; 0.9 / (1 / relay fps + hot remap)). Medians of the same rounds '
              'as above.', '']
    return lines


def cost_lines(results):
    """CPU per frame of every process under test at 30 fps, the executors side by side, with and
    without an image_rect subscriber, against the targets (node <= 1.1 x remap relay with a
    subscriber, <= 1.2 x the pass-through relay without one)."""
    rows = [r for r in results if any(k.endswith('_nosub') or k.startswith('node_events') for k in r)]
    if not rows:
        return []
    nodes = [s for s in ('node', 'node_events', 'baseline', 'node_nosub', 'node_events_nosub', 'baseline_nosub')
             if any(s in r for r in rows)]
    labels = {'node': 'node, subscribed', 'node_events': 'node (events), subscribed',
              'baseline': 'baseline, subscribed', 'node_nosub': 'node, no subscriber',
              'node_events_nosub': 'node (events), no subscriber', 'baseline_nosub': 'baseline, no subscriber'}
    floors = [s for s in ('relay', 'relay_events', 'remap_relay', 'remap_relay_events') if any(s in r for r in rows)]
    cpu = lambda entry: entry.get('cpu_ms_per_frame_median', float('nan'))  # noqa: E731
    yes = lambda ok: 'yes' if ok else '**no**'  # noqa: E731
    lines = ['### Cost per frame at 30 fps: CPU of each process under test', '',
             '| frame | enc | ' + ' | '.join(f'{s} CPU ms/frame' for s in floors + nodes) + ' | '
             'node / remap relay (<= 1.1) | node no subscriber / relay (<= 1.2) | '
             'node (events) / remap relay | node (events) no subscriber / relay |',
             '|---|---|' + '---|' * (len(floors) + len(nodes) + 4)]
    for r in rows:
        relay, remap = cpu(r.get('relay', {})), cpu(r.get('remap_relay', {}))

        def ratio(system, floor, limit):
            if system not in r or not np.isfinite(floor) or floor <= 0:
                return 'n/a'
            value = cpu(r[system]) / floor
            return f'{value:.2f}x ({yes(value <= limit)})'
        r['cost_ratios'] = {s: (cpu(r[s]) / (remap if not s.endswith('_nosub') else relay))
                            for s in ('node', 'node_events', 'node_nosub', 'node_events_nosub') if s in r}
        lines.append(f"| {r['size']} | {r['encoding']} | " +
                     ' | '.join(fmt(cpu(r[s]), 2) if s in r else 'n/a' for s in floors + nodes) + ' | ' +
                     f"{ratio('node', remap, 1.1)} | {ratio('node_nosub', relay, 1.2)} | "
                     f"{ratio('node_events', remap, 1.1)} | {ratio('node_events_nosub', relay, 1.2)} |")
    lines += ['', 'User + system CPU of the process under test (/proc/PID/stat) over the 30 fps phase divided by the '
              'frames sent, median of the rounds (the rounds\' values are in the page-fault table below). '
              'relay: benchmarks/relay_node.py --mode raw (takes and republishes the serialized frame); remap relay: '
              '--mode remap (CameraInfo + remap + publish, nothing else). "no subscriber": nothing subscribes to '
              'image_rect; the subscriber process takes camera_info only. baseline: the node before lazy '
              'rectification (see above), which remaps every frame whoever subscribes.', '']
    lines += ['### The executors side by side (30 fps latency, CPU, drops; highest rate)', '',
              '| frame | enc | image_rect | executor | p50 ms | p99 ms | CPU ms/frame | drops at 30 fps | '
              'max fps | maps built (node log) | rectify (start-up log) |',
              '|---|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        for system in ('node', 'node_events', 'node_nosub', 'node_events_nosub', 'baseline', 'baseline_nosub'):
            if system not in r:
                continue
            e = r[system]
            facts = e.get('diagnostics') or {}
            lines.append(f"| {r['size']} | {r['encoding']} | {'no subscriber' if system.endswith('_nosub') else 'subscribed'} | "
                         f"{'baseline' if system.startswith('baseline') else ('EventsExecutor' if '_events' in system else 'SingleThreaded')} | "
                         f"{fmt(e['p30']['latency_ms'][50], 2)} | {fmt(e['p30']['latency_ms'][99], 2)} | "
                         f"{fmt(cpu(e), 2)} | {e['p30']['lost']}/{e['p30']['sent']} | {fmt(e['max_rate'])} | "
                         f"{maps_text(facts)} | {facts.get('rectify') or 'n/a'} |")
    lines += ['', 'Latency: publisher stamp -> subscriber receive, of image_rect when subscribed, of camera_info '
              'when not (median of the rounds). Max fps: highest offered rate with <= 1 % loss of those messages. '
              '"maps built": rectification map builds in the node\'s log over the run (the last round).', '']
    return lines


def maps_text(facts: dict) -> str:
    """'1 (503 ms)': the map builds of a node's log and how long each took."""
    if 'maps_built' not in facts:
        return 'n/a'
    times = facts.get('maps_build_ms') or []
    return f"{facts['maps_built']}" + (f" ({', '.join(f'{ms} ms' for ms in times)})" if times else '')


def fault_lines(results):
    """Page faults and CPU of each process under test per frame of the 30 fps phase, round by
    round: a frame-sized block faulted in anew every frame shows here (core/streaming/heap.py)."""
    order = ['relay', 'relay_events', 'remap_relay', 'remap_relay_events', 'node', 'node_events', 'node_nosub',
             'node_events_nosub', 'baseline', 'baseline_nosub']
    systems = [system for system in order if any(r.get(system, {}).get('faults_per_frame') for r in results)]
    if not systems:
        return []
    lines = ['### Page faults and CPU per frame at 30 fps (the process under test), round by round', '',
             '| frame | enc | ' + ' | '.join(f'{s} faults / CPU ms' for s in systems) + ' |',
             '|---|---|' + '---|' * len(systems)]

    def cell(entry):
        pairs = zip(entry.get('faults_per_frame') or [], entry.get('cpu_ms_per_frame') or [])
        return ', '.join(f'{fmt(f, 0)} / {fmt(c, 1)}' for f, c in pairs) or 'n/a'

    for r in results:
        lines.append(f"| {r['size']} | {r['encoding']} | " + ' | '.join(cell(r.get(s, {})) for s in systems) + ' |')
    lines += ['', 'Minor page faults and user + system CPU of the relay, remap relay or node process over the '
              '30 fps phase (/proc/PID/stat), divided by the frames sent. Every process of the run '
              'but a baseline from before that setting sets glibc\'s allocator thresholds at start '
              '(`keep_frames_in_heap`).', '']
    return lines


def _run_settings(raw) -> tuple:
    """(quiet-budget minutes, attempts) of a run: recorded, or read from its command line."""
    command = ' '.join(raw.get('header', [''])[:1])
    def option(name, default):
        found = re.search(rf'--{name}[ =]([0-9.]+)', command)
        return float(found.group(1)) if found else default
    return (raw.get('quiet_budget_min', option('quiet-budget', 60.0)), int(raw.get('attempts', option('attempts', 3))))


def load_lines(results, raw=None):
    quiet_budget, attempts = _run_settings(raw or {})
    runs = [run for r in results for runs in r.get('rounds', {}).values() for run in runs]
    if not runs:
        return []
    loads = [float(run['load_at_start']) for run in runs if run.get('load_at_start') is not None]
    others = [run['others_cores'] for run in runs if 'others_cores' in run]
    repeated = sum(run.get('attempt', 1) - 1 for run in runs)
    lines = [f'Machine load: 1-min load average at the start of each measured run (after its warm-up; it '
             f'includes the benchmark\'s own three processes): min {min(loads):.2f}, median '
             f'{float(np.median(loads)):.2f}, max {max(loads):.2f}.']
    if others:
        waits = (f' Each run waited (at most {quiet_budget:g} min over the whole run) until processes outside the '
                 f'benchmark used < {sm.QUIET_CPU:g} cores' if quiet_budget > 0 else
                 ' Runs did not wait for a quiet machine (--quiet-budget 0)')
        again = (f', and was measured again (at most {attempts} times) if they used > {sm.DISTURBED_CPU:g} cores '
                 f'during it: {repeated} run(s) repeated' if attempts > 1 else
                 ', and each was measured once whatever other processes did (--attempts 1)')
        lines[0] += (f'{waits}{again}; CPU of other processes (other helpers\' jobs) during the kept runs: median '
                     f'{float(np.median(others)):.2f}, max {max(others):.2f} cores of 2.')
    return lines + ['']


def comparison_table(comparisons):
    lines = ['| frame | enc | build ours ms | build cv maps ms | frame ours ms | frame cv maps ms | '
             'undistortImage ms/frame | map diff px max / p99 | ours vs cv maps: max / mean / >1 level | '
             'ours vs undistortImage: max / mean / >1 level |',
             '|---|---|---|---|---|---|---|---|---|---|']
    for c in comparisons:
        dv, du = c['diff_vs_cv_maps'], c['diff_vs_undistortImage']
        lines.append(
            f"| {c['size']} | {c['encoding']} | {fmt(c['build_ms']['ours'])} | {fmt(c['build_ms']['cv_maps'])} | "
            f"{fmt(c['frame_ms']['ours'], 2)} | {fmt(c['frame_ms']['cv_maps'], 2)} | "
            f"{fmt(c['frame_ms']['undistortImage'], 2)} | {c['map_err_px']['max']:.4f} / {c['map_err_px']['p99']:.4f} | "
            f"{dv['max']} / {dv['mean']:.3f} / {100 * dv['gt1']:.2f} % | "
            f"{du['max']} / {du['mean']:.3f} / {100 * du['gt1']:.2f} % |")
    return '\n'.join(lines)


def system_kind(system: str) -> tuple:
    """(base, executor, image_rect subscribed) of a system's name: 'node_events_nosub' ->
    ('node', 'events', False); 'remap_relay' -> ('remap_relay', 'single', True)."""
    subscribed = not system.endswith('_nosub')
    name = system if subscribed else system[:-len('_nosub')]
    executor = 'events' if name.endswith('_events') else 'single'
    return (name[:-len('_events')] if executor == 'events' else name), executor, subscribed


def systems_of(remap_relay=True, baseline=False, executors=('single',), no_subscriber=False,
               relay_executors=('single',)) -> list:
    """The systems measured per case, in the order they alternate."""
    suffix = {'single': '', 'events': '_events'}
    systems = [f'relay{suffix[e]}' for e in relay_executors]
    if remap_relay:
        systems += [f'remap_relay{suffix[e]}' for e in relay_executors]
    systems += [f'node{suffix[e]}' for e in executors]
    if no_subscriber:
        systems += [f'node{suffix[e]}_nosub' for e in executors]
    if baseline:
        systems += ['baseline'] + (['baseline_nosub'] if no_subscriber else [])
    return systems


def run_throughput(sizes, encodings, cfg, log_dir, profile_dir=None, baseline_dir=None, rounds=1, attempts=3,
                   remap_relay=True, executors=('single',), no_subscriber=False, relay_executors=('single',)):
    """relay, remap relay and node (and the baseline node, the node's variants) alternately,
    ``rounds`` times each; medians over the rounds (a busy shared machine makes single runs noisy)."""
    results = []
    systems = systems_of(remap_relay, bool(baseline_dir), executors, no_subscriber, relay_executors)
    for size in sizes:
        w, h = bc.SIZES[size]
        for enc in encodings:
            entry = {'size': size, 'encoding': enc, 'rounds': {}}
            entry['remap_ms'] = remap_floor(w, h, enc, cfg['remap_repeat'])
            for round_ in range(rounds):
                for system in systems:
                    run = run_system(system, w, h, enc, cfg, log_dir,
                                     profile_dir if round_ == 0 else None, baseline_dir, attempts=attempts)
                    entry['rounds'].setdefault(system, []).append(run)
            for system, runs in entry['rounds'].items():
                entry[system] = combine_rounds(runs)
            results.append(entry)
    return results


def combine_rounds(runs):
    """Medians over the rounds of latency and max rate; the worst round's drops and RSS."""
    med = lambda values: float(np.median(values))  # noqa: E731
    return {'p30': {'latency_ms': {q: med([r['p30']['latency_ms'][q] for r in runs]) for q in (50, 90, 99)},
                    'lost': max(r['p30']['lost'] for r in runs), 'sent': runs[0]['p30']['sent']},
            'max_rate': med([r['max_rate'] for r in runs]),
            'max_rates': [r['max_rate'] for r in runs],
            'peak_rss_mib': max(r['peak_rss_mib'] for r in runs),
            'profile': next((r['profile'] for r in runs if r.get('profile')), None),
            'alive': all(r['alive'] for r in runs),
            'non_finite_camera_info': sum(r.get('non_finite_camera_info', 0) for r in runs),
            'faults_per_frame': [r.get('p30_faults_per_frame') for r in runs],
            'cpu_ms_per_frame': [r.get('p30_cpu_ms_per_frame') for r in runs],
            'cpu_ms_per_frame_median': med([r.get('p30_cpu_ms_per_frame', float('nan')) for r in runs]),
            'others_cores': [r.get('others_cores') for r in runs],
            'diagnostics': next((r['diagnostics'] for r in reversed(runs) if r.get('diagnostics')), None)}


def node_log_facts(child) -> dict:
    """What the node's log says of a run: the executor and rectify lines of its start-up block,
    and how many times it built rectification maps (none while nobody subscribes to image_rect)."""
    path = getattr(child, '_stderr_path', None)
    try:
        text = Path(path).read_text() if path else ''
    except OSError:
        text = ''
    built = [int(ms) for ms in re.findall(r'rectification maps of .* built in (\d+) ms', text)]
    facts = {'maps_built': len(built), 'maps_build_ms': built}
    for key in ('executor', 'rectify'):
        found = re.search(rf'^  {key} +(.*?)( \(maps at most.*)?$', text, re.M)
        facts[key] = found.group(1).strip() if found else None
    return facts


def run_system(system, w, h, enc, cfg, log_dir, profile_dir, baseline_dir, attempts=3):
    """One system's run of a case on a quiet machine: started once other processes use less than
    sm.QUIET_CPU cores, repeated (at most ``attempts`` times) if they used more than
    sm.DISTURBED_CPU cores during it. The baseline is the message path of the installed node
    (``baseline_dir == 'message'``) or the package exported from a git ref (a directory)."""
    for attempt in range(1, attempts + 1):
        quiet = sm.wait_quiet(what=f'{system} {w}x{h} {enc}')
        result = _run_system_once(system, w, h, enc, cfg, log_dir, profile_dir, baseline_dir)
        result.update(quiet, attempt=attempt)
        if result['others_cores'] <= sm.DISTURBED_CPU or attempt == attempts:
            break
        print(f'#   other processes used {result["others_cores"]:.2f} cores during it: measured again',
              file=sys.stderr, flush=True)
    return result


def _run_system_once(system, w, h, enc, cfg, log_dir, profile_dir, baseline_dir):
    size = f'{w}x{h}'
    print(f'# {system} {size} {enc}  (load {open("/proc/loadavg").read().split()[0]})', file=sys.stderr, flush=True)
    base, executor, subscribed = system_kind(system)
    baseline = base == 'baseline'
    message_path = baseline and str(baseline_dir) == 'message'
    s = Session('node' if baseline else base, w, h, enc, log_dir,
                package_dir=baseline_dir if baseline and not message_path else None,
                target_env={'ZEROSHOT_CALIB_FRAME_PATH': 'message'} if message_path else None,
                rect_subscriber=subscribed, executor=executor, tag=system)
    result = {}
    try:
        s.warm_up()
        load = open('/proc/loadavg').read().split()[0]
        others = sm.OtherCpu()
        faults, cpu = bc.proc_counters(s.target.pid)
        p30 = s.phase('30 fps', 30, cfg['p30_seconds'])
        faults_after, cpu_after = bc.proc_counters(s.target.pid)
        frames = max(1, len(p30.sent))  # per frame offered (0 drops at 30 fps: the same as delivered)
        if cfg.get('p30_only'):  # latency, drops and CPU at 30 fps only: no highest rate
            sat, rate, trials = p30, float('nan'), []
        else:
            sat = s.phase('saturation', 0, cfg['sat_seconds'])
            rate, trials = max_sustained_rate(s, sat.output_rate, cfg['bisect_steps'], cfg['trial_seconds'])
        prof = None
        if profile_dir is not None and system in ('node', 'node_events', 'baseline'):
            path = Path(profile_dir) / f'pyspy-{system}-{size}-{enc}.txt'
            got, _ = profile_target(s, cfg['profile_seconds'], path, max(1.0, 0.9 * rate))
            prof = str(got) if got else None
        result = {'p30': p30.summary(), 'saturation': sat.summary(), 'max_rate': rate,
                  'p30_faults_per_frame': (faults_after - faults) / frames,
                  'p30_cpu_ms_per_frame': (cpu_after - cpu) * 1e3 / frames,
                  'trials': trials, 'peak_rss_mib': s.peak_rss(), 'rss_samples': s.rss[::4],
                  'profile': prof, 'alive': s.target.alive(), 'load_at_start': load,
                  'others_cores': others.cores()}
        if base in ('node', 'baseline'):
            result['non_finite_camera_info'] = sum(1 for v in s.infos.values() if not v[1])
        if base == 'node':
            result['diagnostics'] = node_log_facts(s.target)
    finally:
        s.close()
    print(f'#   p50 {result["p30"]["latency_ms"][50]:.2f} ms, lost@30 {result["p30"]["lost"]}, '
          f'max {result["max_rate"]:.1f} fps, others {result["others_cores"]:.2f} cores', file=sys.stderr, flush=True)
    return result


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--quick', action='store_true', help='short phases (about 5 minutes in all)')
    p.add_argument('--sizes', default=','.join(bc.SIZES))
    p.add_argument('--encodings', default='bgr8,mono8')
    p.add_argument('--skip', default='', help='comma list of: throughput, compare, startup')
    p.add_argument('--profile', action='store_true', help='also py-spy the node (needs py-spy in .venv)')
    p.add_argument('--baseline', default='message', help='the previous node, measured beside the node in '
                   'the same run: "message" (default: the installed node on its message path, '
                   'ZEROSHOT_CALIB_FRAME_PATH=message), a git ref (its committed package, exported '
                   'read-only with git archive, e.g. HEAD) or "none"')
    p.add_argument('--startup-baseline', default='HEAD', help='git ref whose committed node the start-up '
                   'figures (and the import time of the node module) are compared with; "none": not measured')
    p.add_argument('--rounds', type=int, default=None, help='relay/node alternations per case '
                   '(default 2, --quick 1)')
    p.add_argument('--quiet-budget', type=float, default=60.0, help='minutes that all waits for a quiet machine '
                   '(other processes below 0.3 cores) may take together (default 60; 0: never wait)')
    p.add_argument('--attempts', type=int, default=3, help='measurements of a run at most, while other processes '
                   'used more than 0.6 cores during it (default 3; 1: as the machine is, the load recorded)')
    p.add_argument('--no-remap-relay', dest='remap_relay', action='store_false',
                   help='do not measure the remap relay (relay_node.py --mode remap) beside the node')
    p.add_argument('--executors', default='single', help='comma list of the executors the node is measured '
                   'with: single (rclpy\'s SingleThreadedExecutor, the default) and/or events (its '
                   'EventsExecutor, ZEROSHOT_CALIB_EXECUTOR=events)')
    p.add_argument('--relay-executors', default='single', help='the same for the relays')
    p.add_argument('--no-subscriber', action='store_true', help='also measure the node (and the baseline) '
                   'with no image_rect subscriber: the subscriber process takes camera_info only')
    p.add_argument('--p30-only', action='store_true', help='measure the 30 fps phase only (latency, drops, '
                   'CPU per frame), not the highest rate: more rounds in the same time')
    p.add_argument('--out', default=str(bc.RESULTS / 'rectify_throughput.md'))
    p.add_argument('--render', default=None, metavar='JSON', help='only re-render the report of a previous run')
    args = p.parse_args(argv)
    if args.render:
        return render(Path(args.render), Path(args.out))
    bc.install_signal_handlers()
    if not bc.NODE_EXECUTABLE.exists():
        sys.exit(f'{bc.NODE_EXECUTABLE} is missing: run `make build` first')
    sm.WAIT_BUDGET_S[0] = args.quiet_budget * 60
    sizes = [s for s in args.sizes.split(',') if s]
    encodings = [e for e in args.encodings.split(',') if e]
    cfg = ({'p30_seconds': 4, 'sat_seconds': 1.5, 'trial_seconds': 2, 'bisect_steps': 2, 'remap_repeat': 15,
            'profile_seconds': 5} if args.quick else
           {'p30_seconds': 10, 'sat_seconds': 3, 'trial_seconds': 3, 'bisect_steps': 4, 'remap_repeat': 40,
            'profile_seconds': 10})
    cfg['p30_only'] = args.p30_only
    skip = set(args.skip.split(','))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    log_dir = Path(tempfile.mkdtemp(prefix='zeroshot_bench_'))  # child logs, py-spy files
    print(f'logs of the child processes: {log_dir}', file=sys.stderr)
    started = time.time()
    raw = {'config': cfg, 'quick': args.quick, 'rounds': args.rounds or (1 if args.quick else 2),
           'attempts': args.attempts, 'quiet_budget_min': args.quiet_budget,
           'header': [f'Command: `.venv/bin/python benchmarks/rectify_throughput.py {" ".join(argv or sys.argv[1:])}`',
                      f'Date: {time.strftime("%Y-%m-%d %H:%M:%S %Z")}; {bc.versions()}',
                      f'`uptime` before the run: ' + subprocess.run(['uptime'], capture_output=True,
                                                                    text=True).stdout.strip(), '',
                      '```', bc.machine_description(), '```', '']}
    baseline_dir = None
    if args.baseline == 'message':
        baseline_dir = 'message'
        raw['header'] += ['Baseline: the previous node, i.e. the same installed node on its message path '
                          '(`ZEROSHOT_CALIB_FRAME_PATH=message`: each frame deserialised into a sensor_msgs/Image, '
                          'rectified, serialised back), measured in the same run, case by case; the "node" '
                          'takes image_raw as CDR bytes and publishes bytes.', '']
    elif args.baseline and args.baseline != 'none':
        baseline_dir = sm.export_ref(args.baseline)
        sha = subprocess.run(['git', '-C', str(bc.REPO), 'rev-parse', '--short', args.baseline],
                             capture_output=True, text=True).stdout.strip()
        raw['header'] += [f'Baseline: the node as committed at `{args.baseline}` ({sha}), exported with git '
                          'archive; the "node" is the working tree as built into install/.', '']
    if 'throughput' not in skip:
        raw['throughput'] = run_throughput(sizes, encodings, cfg, log_dir, log_dir if args.profile else None,
                                           baseline_dir, raw['rounds'], attempts=args.attempts,
                                           remap_relay=args.remap_relay,
                                           executors=[e for e in args.executors.split(',') if e],
                                           no_subscriber=args.no_subscriber,
                                           relay_executors=[e for e in args.relay_executors.split(',') if e])
    if 'compare' not in skip:
        comparisons = []
        for size in sizes:
            w, h = bc.SIZES[size]
            print(f'# compare {size}', file=sys.stderr, flush=True)
            c = compare_with_opencv(w, h, 'bgr8', 10 if args.quick else 30)
            comparisons.append({'size': size, 'encoding': 'bgr8', **c})
        raw['compare'] = comparisons
    if 'startup' not in skip:
        raw['startup'] = sm.run_all(sizes=[s for s in sizes if s in ('1920x1080', '3840x2160')] or ['1920x1080'],
                                    quick=args.quick, log_dir=log_dir,
                                    baseline=None if args.startup_baseline == 'none' else args.startup_baseline)
    raw['minutes'] = (time.time() - started) / 60
    out.with_suffix('.json').write_text(json.dumps(raw, indent=1, default=str))
    return render(out.with_suffix('.json'), out)


def render(json_path: Path, out: Path):
    """The markdown report of a run's raw results (also: --render JSON)."""
    raw = json.loads(Path(json_path).read_text())
    for entry in raw.get('throughput', []):  # JSON turned the percentile keys into strings
        for system in entry.get('rounds', {}):
            if system in entry:
                lat = entry[system]['p30']['latency_ms']
                entry[system]['p30']['latency_ms'] = {int(k) if k.isdigit() else k: v for k, v in lat.items()}
    report = [f'# Rectification benchmark ({"quick" if raw.get("quick") else "full"} run)', ''] + raw['header']
    if 'throughput' in raw:
        results = raw['throughput']
        report += ['## Throughput and latency: publisher process -> node -> subscriber process', '',
                   throughput_table(results), '',
                   'remap: `cv2.remap` alone on the node\'s maps in one process (median; node\'s thread '
                   'setting), hot = back to back (the strict floor, used for the rate target), paced = one call '
                   'every 33 ms as in a 30 fps stream (idle cores and sleeping OpenCV workers, colder caches). '
                   'Latency: publisher stamp -> subscriber receive at 30 fps (median p50, p99). Target '
                   'latency = relay p50 + remap + 1 ms (with the hot and with the paced remap). Max fps: '
                   'highest offered rate with <= 1 % loss (bisection). Target fps = 0.9 / (1 / relay fps + '
                   f'remap). {raw["rounds"]} round(s) of relay and node (and baseline) alternately per row: '
                   'medians of latency and max fps, the worst round\'s drops and RSS. Relay: '
                   '`benchmarks/relay_node.py --mode raw` (same QoS and process layout, republishes the '
                   'serialised frame unchanged). Three processes share 2 cores, so the publisher and '
                   'subscriber take CPU from the system under test; ratios are from one run.', '']
        report += cost_lines(results)
        report += speedup_lines(results)
        report += stream_floor_lines(results)
        report += fault_lines(results)
        report += load_lines(results, raw)
        report += profile_report(results)
    if 'compare' in raw:
        report += ['## Exact maps vs OpenCV fisheye (image_proc) vs undistortImage per frame', '',
                   comparison_table(raw['compare']), '',
                   'Ours: maps from the exact zero-shot model (`Rectifier`). cv maps: '
                   '`cv2.fisheye.initUndistortRectifyMap(K, D, I, P, CV_16SC2)` from the published '
                   'CameraInfo (what image_proc does), then the same `cv2.remap`. undistortImage: '
                   '`cv2.fisheye.undistortImage(K, D, Knew=P)` on every frame (builds maps each time). '
                   'Map diff: distance between the two maps\' source positions where both see the '
                   'image. Pixel differences: 8-bit levels over the whole bgr8 test frame.', '']
    if 'startup' in raw:
        report += sm.report_lines(raw['startup'])
    if 'minutes' in raw:
        report += [f'Total benchmark time: {raw["minutes"]:.1f} min.', '']
    text = '\n'.join(report)
    print(text)
    out.write_text(text)
    print(f'\nwritten: {out}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
