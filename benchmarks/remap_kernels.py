#!/usr/bin/env python3
"""How fast OpenCV remaps each kind of frame with each map format: the measurements behind
``rectify.map_format_for`` and ``rectify.pads_to_four_channels``.

For every size and encoding, the candidates run alternately, one call each in turn, so that a
noisy machine slows them alike: 3 channels with fixed-point maps (image_proc's), with float
maps, padded to 4 channels with float maps (what the Rectifier does from OpenCV 4.11) and
padded with fixed-point maps; one-channel frames with fixed and with float maps; and the
Rectifier itself (what the node calls). Back to back ("hot") and one call every 33 ms, as in a
30 fps stream ("paced": sleeping OpenCV workers, colder caches). Medians, ms per frame.

    .venv/bin/python benchmarks/remap_kernels.py --out benchmarks/results/remap_kernels.md
    .venv-jazzy-libs/bin/python benchmarks/remap_kernels.py --append benchmarks/results/remap_kernels.md
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / 'benchmarks')]

import bench_common as bc  # noqa: E402

ENCODINGS = {'bgr8': (3, np.uint8), 'bgr16': (3, np.uint16), 'mono8': (1, np.uint8)}


def candidates(width, height, channels, dtype):
    """name -> zero-argument callable, for one frame of that kind."""
    import cv2
    _, rectifier = bc.node_calibration(width, height).for_size(width, height)
    other = 'float' if rectifier.map_format == 'fixed' else 'fixed'
    maps = {rectifier.map_format: (rectifier.map1, rectifier.map2),
            other: tuple(cv2.convertMaps(rectifier.map1, rectifier.map2,
                                         cv2.CV_32FC1 if other == 'float' else cv2.CV_16SC2))}
    image = bc.test_image(width, height, channels)
    if dtype == np.uint16:
        image = image.astype(np.uint16) * 257
    out = np.empty_like(image)

    def remap(fmt, src, dst):
        return lambda: cv2.remap(src, *maps[fmt], cv2.INTER_LINEAR, dst=dst, borderMode=cv2.BORDER_CONSTANT)

    result = {f'{channels} ch, {fmt} maps': remap(fmt, image, out) for fmt in ('fixed', 'float')}
    if channels == 3:
        four, four_out = np.empty((height, width, 4), dtype), np.empty((height, width, 4), dtype)
        for fmt in ('float', 'fixed'):
            def padded(fmt=fmt):
                cv2.cvtColor(image, cv2.COLOR_BGR2BGRA, dst=four)
                cv2.remap(four, *maps[fmt], cv2.INTER_LINEAR, dst=four_out, borderMode=cv2.BORDER_CONSTANT)
                cv2.cvtColor(four_out, cv2.COLOR_BGRA2BGR, dst=out)
            result[f'padded to 4, {fmt} maps'] = padded
    result['Rectifier.rectify'] = lambda: rectifier.rectify(image, out=out)
    return result


def measure(calls, rounds, pause):
    times = {name: [] for name in calls}
    for name, call in calls.items():  # warm: maps and buffers touched once
        call()
    for _ in range(rounds):
        for name, call in calls.items():
            if pause:
                time.sleep(pause)
            t0 = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(t)) * 1e3 for name, t in times.items()}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--sizes', default='1280x720,1920x1080,3840x2160')
    p.add_argument('--encodings', default=','.join(ENCODINGS))
    p.add_argument('--rounds', type=int, default=60, help='calls of each candidate back to back')
    p.add_argument('--paced-rounds', type=int, default=20, help='calls of each candidate, one per 33 ms')
    p.add_argument('--out', type=Path, help='write the markdown here')
    p.add_argument('--append', type=Path, help='append this run (another OpenCV) to that file')
    args = p.parse_args(argv)
    import cv2
    from zeroshot_calib_ros.core.ros_formats.rectify import map_format_for, pads_to_four_channels
    started = time.time()
    lines = [f'## OpenCV {cv2.__version__} ({cv2.getNumThreads()} threads)', '',
             f'Command: `{Path(sys.executable).relative_to(REPO) if str(sys.executable).startswith(str(REPO)) else sys.executable} '
             f'benchmarks/remap_kernels.py {" ".join(argv if argv is not None else sys.argv[1:])}`',
             f'Date: {time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())}; {bc.versions()}; '
             f'load average at start: {open("/proc/loadavg").read().split()[0]}', '',
             f'The Rectifier here: {map_format_for(1)} maps; 3 channels padded to 4: '
             f'{"yes" if pads_to_four_channels(3, 1) else "no"}.', '',
             '| frame | enc | candidate | hot ms | paced ms |', '|---|---|---|---:|---:|']
    for size in args.sizes.split(','):
        width, height = map(int, size.split('x'))
        for encoding in args.encodings.split(','):
            channels, dtype = ENCODINGS[encoding]
            calls = candidates(width, height, channels, dtype)
            hot = measure(calls, args.rounds, 0.0)
            paced = measure(calls, args.paced_rounds, 1 / 30)
            for name in calls:
                lines.append(f'| {size} | {encoding} | {name} | {hot[name]:.2f} | {paced[name]:.2f} |')
            print(f'# {size} {encoding}: ' + ', '.join(f'{n} {hot[n]:.2f}' for n in calls), file=sys.stderr, flush=True)
    lines += ['', f'Time: {time.time() - started:.0f} s.', '']
    text = '\n'.join(lines)
    if args.out:
        header = ['# Remap kernels: ms per frame by map format and channel layout', '',
                  __doc__.split('\n\n')[1].replace('\n', ' '), '', '```', bc.machine_description(), '```', '']
        args.out.write_text('\n'.join(header) + '\n' + text)
    elif args.append:
        with open(args.append, 'a') as f:
            f.write('\n' + text)
    else:
        print(text)


if __name__ == '__main__':
    main()
