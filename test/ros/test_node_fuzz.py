"""Hostile input through the live node, as any process on the domain can send it: generated
set_camera_info requests and SetParameters requests against one running node (rectify on).

After every request: the node is alive; a reply is one line; `success` only when the change is
in force (the CameraInfo shows it, and for set_camera_info the file holds it); a refusal keeps
the calibration, the file and the parameters as they were; every CameraInfo ever received is
finite; the log never shows a traceback. Each case has its expected outcome where the inputs
make it certain (e.g. NaN in K: refused; a plausible calibration: adopted).
"""
import math
import random

import numpy as np
import pytest
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, SetParameters
from sensor_msgs.msg import CameraInfo
from sensor_msgs.srv import SetCameraInfo

from ros_peer import LATCHED, domain_id, parameter_msg, peer, start_node  # noqa: F401
from zeroshot_calib_ros.core.ros_formats.calibration_file import CameraCalibration

CASES = 60  # per surface
SPEC = ['--ros-args', '-p', 'width:=640', '-p', 'height:=480', '-p', 'hfov:=118', '-p', 'vfov:=90',
        '-p', 'rectify:=true', '-p', 'publish_rate:=20.0']
NAN, INF = float('nan'), float('inf')


def finite_info(msg):
    return all(math.isfinite(v) for v in [*msg.k, *msg.d, *msg.r, *msg.p])


def same_info(a, b):
    return ((a.width, a.height, a.distortion_model) == (b.width, b.height, b.distortion_model)
            and np.allclose(a.k, b.k) and np.allclose(a.d, b.d) and np.allclose(a.p, b.p))


def plausible_info(rng):
    """A calibration a cameracalibrator could send for a 640x480 fisheye."""
    f = rng.uniform(200, 400)
    cx, cy = rng.uniform(300, 340), rng.uniform(220, 260)
    msg = CameraInfo(width=640, height=480)
    msg.distortion_model = rng.choice(['equidistant', 'plumb_bob'])
    msg.d = ([rng.uniform(-0.05, 0.05) for _ in range(4)] if msg.distortion_model == 'equidistant'
             else [rng.uniform(-0.2, 0.1), rng.uniform(-0.05, 0.05), 0.0, 0.0, 0.0])
    msg.k = [f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0]
    msg.r = np.eye(3).ravel().tolist()
    fp = f * rng.uniform(0.5, 1.0)
    msg.p = [fp, 0.0, cx, 0.0, 0.0, fp, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def _set(msg, field, index, value):
    values = list(getattr(msg, field))
    values[index] = value
    setattr(msg, field, values)


# (name, mutation, expected: True adopted / False refused / None either, consistently)
CAMERA_INFO_MUTATIONS = [
    ('plausible', lambda m, r: None, True),
    ('nan in K', lambda m, r: _set(m, 'k', r.choice([0, 2, 4, 5]), NAN), False),
    ('inf in K', lambda m, r: _set(m, 'k', r.choice([0, 2, 4, 5]), INF), False),
    ('fx = 0', lambda m, r: _set(m, 'k', 0, 0.0), False),
    ('negative fy', lambda m, r: _set(m, 'k', 4, -300.0), False),
    ('nan in D', lambda m, r: _set(m, 'd', 0, NAN), False),
    ('huge in D', lambda m, r: _set(m, 'd', 0, 1e308), None),
    ('nan in R', lambda m, r: _set(m, 'r', 0, NAN), False),
    ('nan in P', lambda m, r: _set(m, 'p', 0, NAN), False),
    ('P all zero', lambda m, r: setattr(m, 'p', [0.0] * 12), False),
    ('width 0', lambda m, r: setattr(m, 'width', 0), False),
    ('height 0', lambda m, r: setattr(m, 'height', 0), False),
    ('100000 x 100000', lambda m, r: (setattr(m, 'width', 100000), setattr(m, 'height', 100000)), False),
    ('unknown model', lambda m, r: setattr(m, 'distortion_model', r.choice(['fisheye!', 'x' * 300, '\n'])), False),
    ('empty model', lambda m, r: setattr(m, 'distortion_model', ''), None),
    ('D too long', lambda m, r: setattr(m, 'd', list(m.d) + [0.0] * r.randint(1, 40)), None),
    ('D empty', lambda m, r: setattr(m, 'd', []), None),
    ('binning 2', lambda m, r: (setattr(m, 'binning_x', 2), setattr(m, 'binning_y', 2)), None),
    ('roi outside', lambda m, r: (setattr(m.roi, 'x_offset', 600), setattr(m.roi, 'width', 600)), False),
    ('other size, same aspect', lambda m, r: (setattr(m, 'width', 1280), setattr(m, 'height', 960)), None),
]


def latest(infos, peer):
    peer.spin_for(0.15)
    return infos[-1]


def test_generated_set_camera_info_requests(peer, start_node, tmp_path):
    path = tmp_path / 'cam.yaml'
    node = start_node(*SPEC, '-p', f'camera_info_url:=file://{path}')
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    rng = random.Random(20261201)
    in_force = latest(infos, peer)
    outcomes = {'adopted': 0, 'refused': 0}
    for case in range(CASES):
        name, mutate, expected = CAMERA_INFO_MUTATIONS[0] if case < 4 else rng.choice(CAMERA_INFO_MUTATIONS)
        msg = plausible_info(rng)
        mutate(msg, rng)
        file_before = path.read_bytes() if path.exists() else None
        response = peer.call(SetCameraInfo, 'set_camera_info', SetCameraInfo.Request(camera_info=msg))
        what = f'case {case} ({name}): {response.success} {response.status_message!r}'
        assert node.alive(), what
        assert '\n' not in response.status_message and response.status_message, what
        if expected is not None:
            assert response.success == expected, what
        if response.success:
            outcomes['adopted'] += 1
            peer.spin_until(lambda: same_info(infos[-1], msg), 10, f'the adopted calibration of {what}')
            saved = CameraCalibration.load(str(path))
            assert np.allclose(saved.K.ravel(), msg.k) and np.allclose(saved.D, msg.d), what
            in_force = infos[-1]
        else:
            outcomes['refused'] += 1
            assert same_info(latest(infos, peer), in_force), f'calibration lost after {what}'
            assert (path.read_bytes() if path.exists() else None) == file_before, f'file changed: {what}'
    assert all(finite_info(m) for m in infos), 'a non-finite CameraInfo was published'
    assert 'Traceback' not in node.log
    print(f'\nset_camera_info fuzz: {CASES} cases, {outcomes}; {len(infos)} CameraInfo, all finite; '
          '0 tracebacks, 0 false successes')
    assert outcomes['adopted'] >= 4 and outcomes['refused'] >= 10


# parameter -> generated values (any type: the node must refuse wrong types itself)
PARAMETER_VALUES = {
    'width': [320, 640, 0, -1, 100000, 2**40, 640.0, 'wide', True],
    'height': [240, 480, 0, -5, 56250, 480.5, None],
    'hfov': [100, 118.0, 0.0, -10.0, 360.0, 400, NAN, INF, 'x'],
    'vfov': [69, 90.0, 0.0, 179.9, NAN, -INF, [1.0, 2.0]],
    'dfov': [0.0, 133.5, 250.0, NAN],
    'projection': ['auto', 'equisolid', 'wide', 'bogus', '', 3],
    'distortion_model': ['equidistant', 'plumb_bob', 'rational_polynomial', 'EQUIDISTANT', 1.0],
    'balance': [0.0, 0.5, 1.0, -0.1, 1.5, NAN, 1],
    'fov_scale': [0.5, 1.0, 2.0, 0.0, 11.0, INF],
    'interpolation': [0, 1, 2, 4, 3, 7, -1, 1.5],
    'rectify': [True, False, 1, 'yes'],
    'frame_id': ['camera', 'optical', '', 'a' * 300, '\n', 5],
    'camera_name': ['camera', 'other', 'bad name'],
    'publish_rate': [20.0, 5.0, 0.0],
    'max_map_memory_mb': [0, 1, 10**9],
    'circle_diameter': [0.0, 500.0, -1.0, NAN],
    'preset': ['', 'gopro_hero9_wide', 'no_such_camera'],
}


def value_of(msg):
    t = msg.type
    return {ParameterType.PARAMETER_INTEGER: msg.integer_value, ParameterType.PARAMETER_DOUBLE: msg.double_value,
            ParameterType.PARAMETER_STRING: msg.string_value, ParameterType.PARAMETER_BOOL: msg.bool_value,
            }.get(t, ('other', t))


def test_generated_parameter_requests(peer, start_node):
    node = start_node(*SPEC)
    infos = peer.collect(CameraInfo, 'camera_info', LATCHED)
    peer.spin_until(lambda: infos, what='camera_info')
    names = sorted(PARAMETER_VALUES)

    def get_all():
        response = peer.call(GetParameters, '/zeroshot_calib/get_parameters', GetParameters.Request(names=names))
        return dict(zip(names, (value_of(v) for v in response.values)))

    rng = random.Random(1201)
    outcomes = {'adopted': 0, 'refused': 0}
    for case in range(CASES):
        before = get_all()
        info_before = latest(infos, peer)
        chosen = rng.sample(names, rng.randint(1, 3))
        values = {name: rng.choice(PARAMETER_VALUES[name]) for name in chosen}
        request = SetParameters.Request(parameters=[parameter_msg(k, v) for k, v in values.items()])
        results = peer.call(SetParameters, '/zeroshot_calib/set_parameters', request).results
        what = f'case {case} {values}: {[(r.successful, r.reason) for r in results]}'
        assert node.alive(), what
        assert len(results) == len(values) and len({r.successful for r in results}) == 1, \
            f'one request is one change, adopted or refused whole: {what}'
        assert all('\n' not in r.reason for r in results), what
        after = get_all()
        if results[0].successful:
            outcomes['adopted'] += 1
            for name, value in values.items():
                if isinstance(value, float) and isinstance(after[name], float):
                    assert after[name] == pytest.approx(value), what
                elif not (isinstance(value, int) and isinstance(after[name], float)):
                    assert after[name] == value, what
            # the CameraInfo agrees with get_parameters once the new calibration is in force
            peer.spin_until(lambda: (infos[-1].width, infos[-1].height) == (after['width'], after['height'])
                            and infos[-1].distortion_model == after['distortion_model'], 10,
                            f'CameraInfo agreeing with get_parameters after {what}')
            peer.spin_for(1.0)  # the new maps (640x480: milliseconds) and the swap
        else:
            outcomes['refused'] += 1
            assert results[0].reason, what
            assert after == before, f'a refused request changed parameters: {what}'
            assert same_info(latest(infos, peer), info_before), f'calibration changed by a refusal: {what}'
    assert all(finite_info(m) for m in infos), 'a non-finite CameraInfo was published'
    assert 'Traceback' not in node.log
    print(f'\nSetParameters fuzz: {CASES} requests, {outcomes}; {len(infos)} CameraInfo, all finite; '
          '0 tracebacks, 0 false successes')
    assert outcomes['adopted'] >= 3 and outcomes['refused'] >= 10
