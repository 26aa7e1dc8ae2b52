#!/usr/bin/env python3
"""Why a remap in a 30 fps stream takes longer than back to back: ``Rectifier.rectify`` on the
node's maps after each kind of wait. Medians, ms per frame, in two orders:

    blocks       each wait for ``--rounds`` calls in a row (a stream doing only that), the
                 blocks twice over in turn, so that a noisy machine slows them alike
    interleaved  the waits in turn, one call each, round after round (the cores are never idle
                 for long: the spins and the other calls keep them busy in between)

    back to back             no wait (the "hot" remap of rectify_throughput.py's latency target)
    sleep 33 ms              a 30 fps stream: the process idle between frames
    spin 33 ms               the calling thread busy instead of asleep (its core never idles)
    sleep 33 ms, read 64 MB  asleep, then 64 MB read from memory just before (what is left of
                             the frame, the maps and the image in the caches is evicted)
    sleep 33 ms, spin 3 ms   asleep, then 3 ms of work on the calling thread just before

If the frame's data had gone cold in the caches, reading 64 MB just before would make the remap
slower still; if the cores run slowly for a while after idling, any work just before makes it
faster.

    .venv/bin/python benchmarks/idle_remap.py --out benchmarks/results/idle_remap.md
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / 'benchmarks')]

import bench_common as bc  # noqa: E402

FRAME_INTERVAL = 1 / 30


def spin(seconds):
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def waits(memory):
    return {
        'back to back': lambda: None,
        'sleep 33 ms': lambda: time.sleep(FRAME_INTERVAL),
        'spin 33 ms': lambda: spin(FRAME_INTERVAL),
        'sleep 33 ms, read 64 MB': lambda: (time.sleep(FRAME_INTERVAL), memory.sum()),
        'sleep 33 ms, spin 3 ms': lambda: (time.sleep(FRAME_INTERVAL), spin(0.003)),
    }


def measure(width, height, channels, rounds, order):
    _, rectifier = bc.node_calibration(width, height).for_size(width, height)
    image = bc.test_image(width, height, channels)
    out = np.empty_like(image)
    memory = np.ones(64 << 20, np.uint8)
    cases = waits(memory)
    for _ in range(5):
        rectifier.rectify(image, out=out)
    times = {name: [] for name in cases}

    def call(name):
        cases[name]()
        t0 = time.perf_counter()
        rectifier.rectify(image, out=out)
        times[name].append(time.perf_counter() - t0)

    if order == 'blocks':
        for _ in range(2):
            for name in cases:
                for _ in range(max(1, rounds // 2)):
                    call(name)
    else:
        for _ in range(rounds):
            for name in cases:
                call(name)
    return {name: float(np.median(t)) * 1e3 for name, t in times.items()}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--sizes', default='1920x1080,3840x2160')
    p.add_argument('--encodings', default='bgr8,mono8')
    p.add_argument('--rounds', type=int, default=60)
    p.add_argument('--out', type=Path)
    args = p.parse_args(argv)
    names = list(waits(None))
    lines = ['# A remap after each kind of wait (benchmarks/idle_remap.py)', '',
             f'Command: `.venv/bin/python benchmarks/idle_remap.py {" ".join(argv or sys.argv[1:])}`', '',
             f'Date: {time.strftime("%Y-%m-%d %H:%M:%S %Z")}; {bc.versions()}', '',
             '```', bc.machine_description(), '```', '',
             '| order | frame | enc | ' + ' | '.join(names) + ' |', '|---|---|---|' + '---:|' * len(names)]
    for size in args.sizes.split(','):
        w, h = (int(x) for x in size.split('x'))
        for enc in args.encodings.split(','):
            for order in ('blocks', 'interleaved'):
                result = measure(w, h, bc.CHANNELS[enc], args.rounds, order)
                lines.append(f'| {order} | {size} | {enc} | ' + ' | '.join(f'{result[n]:.2f}' for n in names) + ' |')
                print(lines[-1], file=sys.stderr, flush=True)
    lines += ['', f'`Rectifier.rectify` on the node\'s maps (bench_common.node_calibration), ms per frame, median '
              f'of {args.rounds} calls after each wait. See the module docstring.', '']
    text = '\n'.join(lines)
    print(text)
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
