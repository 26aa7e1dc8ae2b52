#!/usr/bin/env python3
"""Bounded soak: the node rectifying a camera-rate stream for minutes, watched for drops,
latency drift and memory growth.

publisher process (30 fps, best effort) -> installed zeroshot_calib node (rectify:=true) ->
subscriber process, with the project's shared-memory DDS profile (see bench_common.py).
Every ``--sample-seconds`` the node's VmRSS is read from /proc/<pid>/status; per minute the
frames sent, received and dropped and the latency percentiles are reported. A straight line
fitted to RSS after the first minute (warm-up: allocator and DDS pools settling) gives the
growth trend.

    .venv/bin/python benchmarks/soak.py                  # 10 minutes, 30 fps, 1920x1080 bgr8
    .venv/bin/python benchmarks/soak.py --minutes 2 --size 3840x2160

Writes benchmarks/results/soak.md (and .json). Stops every process it started, also on
Ctrl-C, at the latest ``--minutes`` + 3 minutes after it started.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_common as bc  # noqa: E402
from rectify_throughput import Session  # noqa: E402


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--minutes', type=float, default=10.0)
    p.add_argument('--rate', type=float, default=30.0)
    p.add_argument('--size', default='1920x1080', choices=sorted(bc.SIZES))
    p.add_argument('--encoding', default='bgr8', choices=sorted(bc.CHANNELS))
    p.add_argument('--sample-seconds', type=float, default=5.0)
    p.add_argument('--out', default=str(bc.RESULTS / 'soak.md'))
    args = p.parse_args(argv)
    bc.install_signal_handlers()
    if not bc.NODE_EXECUTABLE.exists():
        sys.exit(f'{bc.NODE_EXECUTABLE} is missing: run `make build` first')
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    log_dir = Path(tempfile.mkdtemp(prefix='zeroshot_soak_'))  # child logs
    width, height = bc.SIZES[args.size]
    duration = args.minutes * 60.0
    hard_deadline = time.monotonic() + duration + 180.0
    watchdog = threading.Timer(duration + 180.0, lambda: (bc._stop_all(), print('soak: time limit', file=sys.stderr)))
    watchdog.daemon = True
    watchdog.start()
    load_before = open('/proc/loadavg').read().split()[:3]

    session = Session('node', width, height, args.encoding, log_dir)
    sent, samples = [], []
    try:
        session.warm_up()
        t0 = time.monotonic()
        session.pub.send(f'RUN {args.rate} {duration}')
        done = None

        def on_pub(line):
            nonlocal done
            if line.startswith('S '):
                sent.append(int(line[2:]))
            elif line.startswith('DONE'):
                done = line

        next_sample = t0
        while done is None and time.monotonic() < hard_deadline:
            session.pub.drain(on_pub)
            session.pull()
            now = time.monotonic()
            if now >= next_sample:
                st = bc.proc_status(session.target.pid)
                samples.append((now - t0, st.get('VmRSS', float('nan')), st.get('VmHWM', float('nan'))))
                next_sample += args.sample_seconds
                if int(now - t0) % 60 < args.sample_seconds:
                    print(f'# {(now - t0) / 60:.1f} min: sent {len(sent)}, received {len(session.images)}, '
                          f'RSS {samples[-1][1]:.1f} MiB', file=sys.stderr, flush=True)
            if not session.target.alive():
                break
            time.sleep(0.2)
        time.sleep(1.0)
        session.pull()
        alive = session.target.alive()
        peak = session.peak_rss()
        node_log_tail = ' | '.join(session.target.other[-5:])
    finally:
        session.close()
    watchdog.cancel()

    received = {s: session.images[s] for s in sent if s in session.images}
    infos = session.infos
    t_first = sent[0] if sent else 0
    minutes = []
    for m in range(int(np.ceil(duration / 60.0))):
        lo, hi = t_first + m * 60e9, t_first + (m + 1) * 60e9
        s_m = [s for s in sent if lo <= s < hi]
        lat = np.array([(received[s] - s) * 1e-6 for s in s_m if s in received])
        minutes.append({'minute': m + 1, 'sent': len(s_m), 'received': int(len(lat)), 'dropped': len(s_m) - len(lat),
                        'p50': bc.percentile(lat, 50), 'p99': bc.percentile(lat, 99),
                        'max': float(lat.max()) if len(lat) else float('nan'),
                        'rss': float(np.nanmean([r for t, r, _ in samples if m * 60 <= t < (m + 1) * 60]))
                        if any(m * 60 <= t < (m + 1) * 60 for t, _, _ in samples) else float('nan')})
    lat_all = np.array([(r - s) * 1e-6 for s, r in received.items()])
    t = np.array([s[0] for s in samples])
    rss = np.array([s[1] for s in samples])
    fit_mask = t >= 60.0 if (t >= 60.0).sum() >= 5 else np.ones_like(t, bool)
    slope = float(np.polyfit(t[fit_mask] / 60.0, rss[fit_mask], 1)[0]) if fit_mask.sum() >= 2 else float('nan')
    unpaired = sum(1 for s in received if s not in infos)
    non_finite = sum(1 for v in infos.values() if not v[1])
    growth_10min = slope * 10.0
    verdict = ('no growth trend' if abs(growth_10min) < max(2.0, 0.01 * float(np.nanmax(rss)))
               else f'RSS trend {slope:+.3f} MiB/min')
    dropped = len(sent) - len(received)
    report = [
        f'# Soak: {args.minutes:g} min at {args.rate:g} fps, {args.size} {args.encoding}', '',
        f'Command: `.venv/bin/python benchmarks/soak.py {" ".join(argv or sys.argv[1:])}`',
        f'Date: {time.strftime("%Y-%m-%d %H:%M:%S %Z")}; {bc.versions()}; load average before: '
        f'{" ".join(load_before)}', '',
        '```', bc.machine_description(), '```', '',
        f'* node alive at the end: {"yes" if alive else "**no**"}',
        f'* frames sent {len(sent)}, rectified and received {len(received)}, dropped {dropped} '
        f'({100.0 * dropped / max(1, len(sent)):.3f} %)',
        f'* latency publisher -> subscriber (ms): p50 {bc.percentile(lat_all, 50):.1f}, p90 '
        f'{bc.percentile(lat_all, 90):.1f}, p99 {bc.percentile(lat_all, 99):.1f}, p99.9 '
        f'{bc.percentile(lat_all, 99.9):.1f}, max {float(lat_all.max()) if len(lat_all) else float("nan"):.1f}',
        f'* image_rect frames without a CameraInfo of the same stamp: {unpaired}; CameraInfo with '
        f'non-finite numbers: {non_finite}',
        f'* node RSS: first sample {rss[0]:.1f} MiB, last {rss[-1]:.1f} MiB, peak (VmHWM) {peak:.1f} MiB; '
        f'least-squares slope after minute 1: {slope:+.4f} MiB/min ({growth_10min:+.2f} MiB per 10 min): '
        f'**{verdict}**', '',
        '| minute | sent | received | dropped | p50 ms | p99 ms | max ms | mean RSS MiB |',
        '|---|---|---|---|---|---|---|---|']
    for m in minutes:
        report.append(f"| {m['minute']} | {m['sent']} | {m['received']} | {m['dropped']} | {m['p50']:.1f} | "
                      f"{m['p99']:.1f} | {m['max']:.1f} | {m['rss']:.1f} |")
    if not alive:
        report += ['', f'Node log tail: {node_log_tail}']
    text = '\n'.join(report) + '\n'
    print(text)
    out.write_text(text)
    out.with_suffix('.json').write_text(json.dumps(
        {'minutes': minutes, 'rss_samples': samples, 'slope_mib_per_min': slope, 'sent': len(sent),
         'received': len(received), 'unpaired': unpaired, 'non_finite': non_finite, 'alive': alive}, indent=1))
    print(f'written: {out}', file=sys.stderr)
    return 0 if alive else 1


if __name__ == '__main__':
    sys.exit(main())
