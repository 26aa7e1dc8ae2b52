#!/usr/bin/env python3
"""Seconds per frame of ``refine_from_images``, and where they go: the current code against a git ref.

Cases: rendered 1920x1080 frames (``test/scenes.py``, the ``room`` scene from random poses)
through two real lens profiles (a GoPro HERO5's 118-degree mode, and a RunCam Thumb Pro's
165-degree mode with the nuisances of real fisheye photos: a vignetted image circle, a vehicle body
part, blur, noise, JPEG), ``--frames`` frames each, and the real photos of
``benchmarks/data/real_cameras/`` that are present (``real_photos.py``'s cameras and specs).

Each case runs in a fresh Python process (what a user of ``zeroshot-calib refine`` waits for:
the lazy imports count) on the current checkout and, with ``--before REF``, on REF checked out
into a temporary ``git worktree``, alternating between the two (after, before, before, after,
...) so that a machine whose load changes during the run slows both alike. The split: region
(``find_image_region``), detection (everything else outside the fits: views, segments, merging,
the zero-shot solution) and fit (``refine_camera``, both rounds), from wrappers put around those
functions in the worker process; the code measured is not changed. The outcome (accepted, f and
principal point) is printed beside the time, to show the change made it faster, not different.

    .venv/bin/python benchmarks/refine_speed.py --before main [--frames 4] [--repeats 1] [--workers N] \\
        [--out benchmarks/results/refine_speed.md]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

RENDERED = {
    # name: (fx, fy, cx, cy, D) at 1920x1080 (the lens profiles' 3840x2160 modes halved)
    'gopro_hero5_118deg': (878.5766, 878.7007, 963.2664, 538.3170,
                           (0.048518656066132336, 0.020626177987878528, -0.01281364507825691, 0.003608125649544864)),
    'runcam_thumbpro_165deg': (653.6974, 652.0635, 951.9705, 551.6628,
                               (-0.00934666389388594, 0.00011060241721791727, -0.008596229987728363,
                                0.006001936526500502)),
}
NUISANCES = {'gopro_hero5_118deg': 'none', 'runcam_thumbpro_165deg': 'all'}
CIRCLE = 0.47
"""With nuisances, the image circle's radius as a fraction of the shorter side (line_refinement.py's)."""


# ---------------------------------------------------------------------------------------------- worker

WORKER = r'''
import json, sys, time
job = json.loads(sys.argv[1])
import cv2
from zeroshot_calib_ros.core.estimation import refine as refine_module
from zeroshot_calib_ros.core.lines import detect as detect_module, image_region as region_module
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec
spent = {'region': 0.0, 'fit': 0.0}

def timed(module, name, key):
    inner = getattr(module, name)
    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            spent[key] += time.perf_counter() - start
    setattr(module, name, wrapper)

timed(region_module, 'find_image_region', 'region')
timed(refine_module, 'refine_camera', 'fit')
images = [cv2.imread(p, cv2.IMREAD_GRAYSCALE) for p in job['images']]
spec = CameraSpec(**job['spec'])
start = time.perf_counter()
result = refine_module.refine_from_images(spec, images, workers=job['workers'])
total = time.perf_counter() - start
camera = result.camera
print(json.dumps({'total': total, 'region': spent['region'], 'fit': spent['fit'],
                  'detection': total - spent['region'] - spent['fit'], 'accepted': bool(result.accepted),
                  'f': float(camera.fx), 'cx': float(camera.cx), 'cy': float(camera.cy),
                  'lines': int(result.lines_used)}))
'''


def run_worker(checkout: Path, job: dict) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout), OMP_NUM_THREADS=os.environ.get('OMP_NUM_THREADS', ''))
    if not env['OMP_NUM_THREADS']:
        del env['OMP_NUM_THREADS']
    done = subprocess.run([sys.executable, '-c', WORKER, json.dumps(job)], env=env, cwd=str(checkout),
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f'worker in {checkout} failed:\n{done.stderr[-3000:]}')
    return json.loads(done.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------------------------------- cases

def rendered_cases(frames: int, directory: Path):
    """(name, size, spec kwargs, image paths, nuisances) of the rendered cases, rendered once into
    ``directory`` by this checkout's test/scenes.py."""
    sys.path[:0] = [str(ROOT), str(ROOT / 'benchmarks'), str(ROOT / 'test')]
    import cv2
    import numpy as np
    import lens_profiles as lp
    import scenes
    from zeroshot_calib_ros.core.lens.wide_fov import fields_of_view_through_axis
    cases = []
    for name, (fx, fy, cx, cy, D) in RENDERED.items():
        f = (fx + fy) / 2
        truth = lp.GroundTruthCamera(f, f, cx, cy, 1920, 1080, np.array(D))
        spec = dict(width=1920, height=1080, **fields_of_view_through_axis(truth))
        nuisances = None
        if NUISANCES[name] == 'all':
            radius = CIRCLE * 1080
            ray = truth.unproject(np.array([[cx + radius, cy]]))[0]
            spec.update(circle_diameter=2 * radius,
                        circle_fov=2 * math.degrees(math.atan2(math.hypot(ray[0], ray[1]), ray[2])))
            nuisances = scenes.Nuisances(circle_radius=radius, vehicle=True, blur=0.6, noise=2.0, jpeg_quality=80)
        paths = []
        for v in range(frames):
            path = directory / f'{name}_{v}.png'
            if not path.exists():
                scene = scenes.make_scene('room', 7)
                image, _ = scenes.render(truth, scene, pose=scenes.random_pose(scene, 70 + v), seed=70 + v,
                                         nuisances=nuisances)
                cv2.imwrite(str(path), image)
            paths.append(str(path))
        cases.append((f'{name}, rendered, nuisances {NUISANCES[name]}', '1920x1080', spec, paths))
    return cases


def real_cases(frames: int, only):
    """The real photos present: (name, size, spec kwargs, image paths)."""
    sys.path[:0] = [str(ROOT), str(ROOT / 'benchmarks')]
    import real_photos as rp
    cases = []
    for camera in rp.load_cameras():
        if only and camera.name not in only:
            continue
        if not camera.photos:
            continue
        spec = rp.spec_of(camera)
        kwargs = {k: getattr(spec, k) for k in ('width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter',
                                                'circle_fov') if getattr(spec, k, None) is not None}
        paths = [str(p) for p in rp.evenly(camera.photos, frames)]
        cases.append((f'{camera.name}, real', f'{camera.width}x{camera.height}', kwargs, paths))
    return cases


# ---------------------------------------------------------------------------------------------- report

def _mean(runs, key):
    return sum(r[key] for r in runs) / len(runs)


def _split(runs, frames):
    return (f"{_mean(runs, 'total') / frames:.2f} ({_mean(runs, 'region') / frames:.2f} / "
            f"{_mean(runs, 'detection') / frames:.2f} / {_mean(runs, 'fit') / frames:.2f})")


def _outcome(r):
    return (f"{'accepted' if r['accepted'] else 'refused'}, f {r['f']:.2f}, pp ({r['cx']:.2f}, {r['cy']:.2f}), "
            f"{r['lines']} lines")


def report(rows, before: str, command: str, seconds: float, workers: int) -> str:
    head = ['## refine_from_images: seconds per frame', '',
            f'`{command}` ({seconds:.0f} s; {os.cpu_count()} cores; load average at the end '
            f'{os.getloadavg()[0]:.1f}; workers {workers}, as `zeroshot-calib refine` on this machine).', '',
            'Seconds per frame: total (region / detection / fit), the mean over the repeats, each a fresh process '
            '(the lazy imports count); the two versions alternate. Outcome: what refine_from_images returned.', '']
    if before:
        head += [f'| case | size | frames | before ({before}) s/frame | after s/frame | speed-up | before outcome '
                 '| after outcome |', '|---|---|---:|---:|---:|---:|---|---|']
    else:
        head += ['| case | size | frames | s/frame | outcome |', '|---|---|---:|---:|---|']
    for name, size, frames, after, prior in rows:
        if before:
            ratio = _mean(prior, 'total') / _mean(after, 'total')
            head.append(f'| {name} | {size} | {frames} | {_split(prior, frames)} | {_split(after, frames)} | '
                        f'{ratio:.2f}x | {_outcome(prior[0])} | {_outcome(after[0])} |')
        else:
            head.append(f'| {name} | {size} | {frames} | {_split(after, frames)} | {_outcome(after[0])} |')
    return '\n'.join(head) + '\n'


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--before', help='a git ref to compare with (checked out into a temporary worktree)')
    parser.add_argument('--frames', type=int, default=4, help='frames per case (default %(default)s)')
    parser.add_argument('--repeats', type=int, default=1, help='runs per case and version (default %(default)s)')
    parser.add_argument('--real', default='mynteye_s_jpl_left,ocam_fisheye190',
                        help='comma-separated real cameras (real_photos.py names; "" for none; default %(default)s)')
    parser.add_argument('--no-rendered', action='store_true', help='leave out the rendered cases')
    parser.add_argument('--workers', type=int, default=os.cpu_count() or 1,
                        help="refine_from_images' workers (default: the machine's cores, as `zeroshot-calib refine`)")
    parser.add_argument('--out', help='write the markdown report here too')
    args = parser.parse_args(argv)
    command = 'benchmarks/refine_speed.py ' + ' '.join(argv if argv is not None else sys.argv[1:])
    start = time.perf_counter()
    work = Path(tempfile.mkdtemp(prefix='refine_speed_'))
    before_tree = None
    try:
        if args.before:
            before_tree = work / 'before'
            subprocess.run(['git', '-C', str(ROOT), 'worktree', 'add', '--detach', str(before_tree), args.before],
                           check=True, capture_output=True)
        renders = work / 'renders'
        renders.mkdir()
        cases = [] if args.no_rendered else rendered_cases(args.frames, renders)
        only = [n for n in args.real.split(',') if n]
        cases += real_cases(args.frames, only) if only else []
        rows = []
        for name, size, spec, paths in cases:
            job = {'spec': spec, 'images': paths, 'workers': args.workers}
            after, prior = [], []
            for k in range(args.repeats):
                order = [(ROOT, after), (before_tree, prior)] if before_tree else [(ROOT, after)]
                for checkout, runs in (order if k % 2 == 0 else order[::-1]):
                    runs.append(run_worker(checkout, job))
                    print(f'{name} [{"after" if checkout == ROOT else "before"}] '
                          f"{runs[-1]['total'] / len(paths):.2f} s/frame {_outcome(runs[-1])}",
                          file=sys.stderr, flush=True)
            rows.append((name, size, len(paths), after, prior))
        text = report(rows, args.before, command.strip(), time.perf_counter() - start, args.workers)
        print(text, end='')
        if args.out:
            with open(args.out, 'w') as f:
                f.write(text)
    finally:
        if before_tree is not None:
            subprocess.run(['git', '-C', str(ROOT), 'worktree', 'remove', '--force', str(before_tree)],
                           capture_output=True)
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
