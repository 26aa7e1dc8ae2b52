"""Byte-identical outputs of two source trees: what a refactoring must not change.

    .venv/bin/python tools/same_outputs.py --before efa20c1            # against this checkout
    .venv/bin/python tools/same_outputs.py --before efa20c1 --after HEAD~2 --keep /tmp/outs

Each tree (a git commit, checked out into a temporary worktree, or a directory) runs the same
cases, and every output is compared byte for byte:
- the CLI: stdout, stderr and exit status of every verb (text, --json, --yaml files and the
  files they write, batch CSV, refusals, bad input);
- the ROS node, started from the tree's entry point as `ros2 run` starts it: the first
  CameraInfo it publishes (serialized CDR, stamp zeroed) for spec, preset-like and file
  parameters, and its log (timestamps and PIDs blanked).

numpy 1.26 on an AVX-512 CPU rounds by memory alignment, so two runs of one fit may differ in
the last digits; the cases run with those kernels off (NPY_DISABLE_CPU_FEATURES), which makes
every run of one tree reproducible. Exit status 0: identical; 1: a difference (listed).
"""
from __future__ import annotations

import argparse
import difflib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get('ZEROSHOT_SHARED_DATA', REPO.parent / 'shared' / 'data')) / 'ros_fisheye_800x503'
MYNT = REPO / 'benchmarks' / 'data' / 'real_cameras' / 'mynteye_s_jpl' / 'left_fisheye_img_0.png'
AVX512 = 'AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR AVX512_KNL AVX512_KNM'

# (name, arguments); {tmp} is the case's own directory (the files it writes are compared too)
CLI_CASES = [
    ('version', ['--version']),
    ('help', ['--help']),
    ('help_solve', ['solve', '--help']),
    ('help_refine', ['refine', '--help']),
    ('help_calibrate', ['calibrate', '--help']),
    ('help_evaluate', ['evaluate', '--help']),
    ('help_rectify', ['rectify', '--help']),
    ('presets', ['presets']),
    ('solve_two_fovs', ['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69']),
    ('solve_one_fov', ['solve', '--width', '1920', '--height', '1080', '--hfov', '118']),
    ('solve_dfov', ['solve', '--width', '1280', '--height', '720', '--dfov', '160']),
    ('solve_three', ['solve', '--width', '800', '--height', '503', '--hfov', '180.81', '--vfov', '103.52',
                     '--dfov', '200']),
    ('solve_json', ['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69', '--json']),
    ('solve_yaml', ['solve', '--width', '800', '--height', '503', '--hfov', '180.81', '--vfov', '103.52',
                    '--yaml', '{tmp}/camera.yaml', '--camera-name', 'front']),
    ('solve_plumb_bob', ['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '69',
                         '--distortion-model', 'plumb_bob', '--yaml', '{tmp}/pb.yaml']),
    ('solve_circle', ['solve', '--width', '1920', '--height', '1080', '--circle-diameter', '1000',
                      '--circle-fov', '200']),
    ('solve_circle_json', ['solve', '--width', '1920', '--height', '1080', '--circle-diameter', '1000',
                           '--circle-fov', '200', '--json']),
    ('solve_preset', ['solve', '--preset', 'gopro_hero9_wide']),
    ('solve_preset_yaml', ['solve', '--preset', 'gopro_hero9_wide', '--yaml', '{tmp}/gopro.yaml']),
    ('solve_models', ['solve', '--width', '1280', '--height', '960', '--hfov', '150', '--vfov', '110',
                      '--model', 'equisolid']),
    ('solve_wide', ['solve', '--width', '1280', '--height', '960', '--hfov', '200', '--vfov', '150',
                    '--model', 'wide', '--yaml', '{tmp}/wide.yaml']),
    ('solve_bad_vfov', ['solve', '--width', '1920', '--height', '1080', '--hfov', '118', '--vfov', '-3']),
    ('solve_swapped', ['solve', '--width', '1920', '--height', '1080', '--hfov', '69', '--vfov', '118']),
    ('solve_no_fov', ['solve', '--width', '1920', '--height', '1080']),
    ('solve_batch', ['solve', '--batch', '{tmp}/cameras.csv', '--yaml-dir', '{tmp}/yamls']),
    ('solve_batch_json', ['solve', '--batch', '{tmp}/cameras.csv', '--json']),
    ('solve_batch_bad', ['solve', '--batch', '{tmp}/bad.csv']),
    ('solve_report', ['solve', '--width', '800', '--height', '503', '--hfov', '180.81', '--vfov', '103.52',
                      '--report', '{tmp}/report_solve.png']),
    ('rectify', ['rectify', str(MYNT), '-o', '{tmp}/rectified.png', '--hfov', '121.4', '--vfov', '76',
                 '--dfov', '147.3']),
    ('rectify_yaml', ['rectify', str(MYNT), '-o', '{tmp}/rectified.png', '--calibration', '{tmp}/given.yaml']),
    ('rectify_missing', ['rectify', '{tmp}/nope.png', '-o', '{tmp}/out.png', '--hfov', '120', '--vfov', '80']),
    ('refine_mynteye', ['refine', str(MYNT), '--hfov', '121.4', '--vfov', '76', '--dfov', '147.3',
                        '--yaml', '{tmp}/mynteye_left.yaml', '--json']),
    ('refine_mynteye_text', ['refine', str(MYNT), '--hfov', '121.4', '--vfov', '76', '--dfov', '147.3']),
    ('refine_bad', ['refine', str(MYNT), '--hfov', '121.4', '--vfov', '200']),
    ('calibrate', ['calibrate', str(SHARED / 'left-000*.png'), '--board', '8x6', '--square', '0.108',
                   '--save-corners', '{tmp}/corners.json', '--yaml', '{tmp}/calibrated.yaml']),
    ('calibrate_json', ['calibrate', str(SHARED / 'left-000*.png'), '--board', '8x6', '--square', '0.108',
                        '--json']),
    ('calibrate_spec', ['calibrate', str(SHARED / 'left-000*.png'), '--board', '8x6', '--square', '0.108',
                        '--hfov', '180.81', '--vfov', '103.52', '--json']),
    ('evaluate', ['evaluate', str(SHARED / 'left-000*.png'), '--board', '8x6', '--square', '0.108',
                  '--hfov', '180.81', '--vfov', '103.52', '--shots', '0', '--json']),
]

CSV = ('name,width,height,hfov,vfov,dfov\nfront,1920,1080,118,69,\nrear,1280,720,,,160\n'
       'side,800,503,180.81,103.52,\n')
BAD_CSV = 'name,width,height,hfov,vfov\nfront,1920,abc,118,69\n'
GIVEN_YAML = """image_width: 752
image_height: 480
camera_name: mynteye
camera_matrix:
  rows: 3
  cols: 3
  data: [356.0, 0.0, 376.0, 0.0, 356.0, 240.0, 0.0, 0.0, 1.0]
distortion_model: equidistant
distortion_coefficients:
  rows: 1
  cols: 4
  data: [0.01, -0.005, 0.001, 0.0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
projection_matrix:
  rows: 3
  cols: 4
  data: [356.0, 0.0, 376.0, 0.0, 0.0, 356.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0]
"""

# (name, node arguments after --ros-args)
NODE_CASES = [
    ('node_two_fovs', ['-p', 'width:=1920', '-p', 'height:=1080', '-p', 'hfov:=118', '-p', 'vfov:=69']),
    ('node_one_fov', ['-p', 'width:=1920', '-p', 'height:=1080', '-p', 'hfov:=118.0']),
    ('node_params_file', ['--params-file', str(REPO / 'config' / 'hero9_w1.yaml'),
                          '-r', '__ns:=/robot', '-r', 'camera_info:=front/camera_info']),
    ('node_file', ['-p', 'camera_info_url:=file://{tmp}/given.yaml', '-p', 'width:=752', '-p', 'height:=480',
                   '-p', 'hfov:=121.4', '-p', 'vfov:=76.0']),
    ('node_bad', ['-p', 'width:=1920', '-p', 'height:=1080', '-p', 'hfov:=118', '-p', 'vfov:=400']),
]


def checkout(revision: str, into: Path) -> Path:
    subprocess.run(['git', '-C', str(REPO), 'worktree', 'add', '--detach', '-f', str(into), revision],
                   check=True, capture_output=True)
    # data that is not in git (fetched real cameras) is read from this checkout
    return into


def remove_checkout(path: Path):
    subprocess.run(['git', '-C', str(REPO), 'worktree', 'remove', '--force', str(path)], capture_output=True)


def environment(tree: Path) -> dict:
    env = dict(os.environ)
    env['PYTHONPATH'] = str(tree)
    env['NPY_DISABLE_CPU_FEATURES'] = AVX512
    env['COLUMNS'] = '100'  # argparse's help layout
    env.pop('ZEROSHOT_CALIB_PROGRESS', None)
    return env


def prepare(tmp: Path):
    tmp.mkdir(parents=True, exist_ok=True)
    (tmp / 'cameras.csv').write_text(CSV)
    (tmp / 'bad.csv').write_text(BAD_CSV)
    (tmp / 'given.yaml').write_text(GIVEN_YAML)


def normalise(text: str, tree: Path, tmp: Path) -> str:
    text = text.replace(str(tmp), '<TMP>').replace(str(tree), '<TREE>').replace(str(REPO), '<TREE>')
    text = re.sub(r'\[\d{9,}\.\d+\]', '[<TIME>]', text)          # ROS log stamps
    text = re.sub(r'\b(\d+(\.\d+)?) s\b(?= (total|in|per)|\)|,|$)', '<S> s', text)  # run times in text
    text = re.sub(r'"seconds": [0-9.e-]+', '"seconds": <S>', text)
    text = re.sub(r'pid \d+', 'pid <PID>', text)
    return text


def run_cli_cases(tree: Path, out: Path, python: str, only=None):
    for name, args in CLI_CASES:
        if only and not re.search(only, name):
            continue
        tmp = out / name
        prepare(tmp)
        argv = [a.replace('{tmp}', str(tmp)) for a in args]
        done = subprocess.run([python, '-c', 'import sys; from zeroshot_calib_ros.cli import main; '
                                             'sys.exit(main(sys.argv[1:]))', *argv],
                              env=environment(tree), cwd=str(tmp), capture_output=True, text=True, timeout=900)
        (tmp / '_stdout').write_text(normalise(done.stdout, tree, tmp))
        (tmp / '_stderr').write_text(normalise(done.stderr, tree, tmp))
        (tmp / '_status').write_text(str(done.returncode))
        print(f'  {name}: exit {done.returncode}', flush=True)


NODE_PEER = r'''
import os, sys, time
import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo
topic, out = sys.argv[1], sys.argv[2]
rclpy.init()
node = rclpy.create_node('same_outputs_peer')
got = []
qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
node.create_subscription(CameraInfo, topic, got.append, qos)
end = time.monotonic() + 20
while not got and time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.1)
if got:
    msg = got[0]
    msg.header.stamp.sec = 0
    msg.header.stamp.nanosec = 0
    open(out, 'wb').write(serialize_message(msg))
node.destroy_node()
rclpy.shutdown()
'''


def run_node_cases(tree: Path, out: Path, python: str, domain: int, only=None):
    env = environment(tree)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               RMW_IMPLEMENTATION='rmw_fastrtps_cpp',
               FASTDDS_DEFAULT_PROFILES_FILE=str(REPO / 'config' / 'fastdds_shm.xml'),
               FASTRTPS_DEFAULT_PROFILES_FILE=str(REPO / 'config' / 'fastdds_shm.xml'), PYTHONUNBUFFERED='1')
    site = next((REPO / 'install' / 'zeroshot_calib_ros' / 'lib').glob('python3*/site-packages'), None)
    env['AMENT_PREFIX_PATH'] = f"{REPO / 'install' / 'zeroshot_calib_ros'}:{REPO / '.venv'}"
    entry = re.search(r"node = ([\w.]+):(\w+)", (tree / 'setup.py').read_text())
    module, function = entry.group(1), entry.group(2)
    for name, args in NODE_CASES:
        if only and not re.search(only, name):
            continue
        tmp = out / name
        prepare(tmp)
        env['ROS_HOME'] = str(tmp / 'ros_home')
        argv = [a.replace('{tmp}', str(tmp)) for a in args]
        topic = '/robot/front/camera_info' if '__ns:=/robot' in argv else '/camera_info'
        log = open(tmp / '_log', 'w')
        node = subprocess.Popen([python, '-c', f'import sys; from {module} import {function} as m; sys.exit(m())',
                                 '--ros-args', *argv], env=env, cwd=str(tmp), stdout=log, stderr=subprocess.STDOUT)
        subprocess.run([python, '-c', NODE_PEER, topic, str(tmp / '_camera_info.cdr')], env=env, timeout=60)
        time.sleep(0.5)
        node.send_signal(2)
        try:
            status = node.wait(timeout=15)
        except subprocess.TimeoutExpired:
            node.kill()
            status = node.wait()
        log.close()
        text = (tmp / '_log').read_text()
        (tmp / '_log').write_text(normalise(text, tree, tmp))
        (tmp / '_status').write_text(str(status))
        shutil.rmtree(tmp / 'ros_home', ignore_errors=True)
        print(f'  {name}: exit {status}, CameraInfo {"yes" if (tmp / "_camera_info.cdr").exists() else "none"}',
              flush=True)
        domain += 1


def compare(a: Path, b: Path) -> list:
    differences = []
    files_a = {p.relative_to(a) for p in a.rglob('*') if p.is_file()}
    files_b = {p.relative_to(b) for p in b.rglob('*') if p.is_file()}
    for missing in sorted(files_a ^ files_b):
        differences.append(f'{missing}: only {"before" if missing in files_a else "after"}')
    for name in sorted(files_a & files_b):
        x, y = (a / name).read_bytes(), (b / name).read_bytes()
        if x != y:
            try:
                diff = '\n'.join(list(difflib.unified_diff(x.decode().splitlines(), y.decode().splitlines(),
                                                           'before', 'after', lineterm=''))[:30])
            except UnicodeDecodeError:
                diff = f'    binary, {len(x)} against {len(y)} bytes'
            differences.append(f'{name}: differs\n{diff}')
    return differences


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--before', required=True, help='git revision (or a directory) before the change')
    parser.add_argument('--after', default=None, help='git revision or directory after (default: this checkout)')
    parser.add_argument('--python', default=str(REPO / '.venv' / 'bin' / 'python'))
    parser.add_argument('--keep', help='keep the outputs in this directory')
    parser.add_argument('--only', help='run only the cases whose name matches this regular expression')
    parser.add_argument('--no-node', action='store_true', help='the CLI cases only')
    args = parser.parse_args(argv)
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix='same_outputs_'))
    if args.keep and work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    trees, made = {}, []
    try:
        for side, revision in (('before', args.before), ('after', args.after)):
            if revision is None:
                trees[side] = REPO
            elif Path(revision).is_dir():
                trees[side] = Path(revision).resolve()
            else:
                trees[side] = checkout(revision, work / f'tree_{side}')
                made.append(trees[side])
        domain = 150 + os.getpid() % 50
        for side, tree in trees.items():
            print(f'{side}: {tree}', flush=True)
            run_cli_cases(tree, work / side, args.python, args.only)
            if not args.no_node:
                run_node_cases(tree, work / side, args.python, domain, args.only)
        differences = compare(work / 'before', work / 'after')
    finally:
        for tree in made:
            remove_checkout(tree)
    if not SHARED.is_dir():
        print(f'note: {SHARED} is missing: the calibrate and evaluate cases only check their error', flush=True)
    cases = len([1 for _ in (work / 'before').iterdir()])
    files = len([1 for p in (work / 'before').rglob('*') if p.is_file()])
    if differences:
        print(f'{len(differences)} of {files} outputs differ ({cases} cases):')
        print('\n'.join(differences))
        return 1
    print(f'identical: {files} outputs of {cases} cases (CLI and node), before {args.before}, '
          f'after {args.after or "this checkout"}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
