"""The pure helpers of benchmarks/gate_stability.py: the perturbations produce what they claim,
flips and changes are counted as the report says, and the cases are real_photos.py's cameras and
line_refinement.py's lenses. No refinement is run here (the benchmark itself is slow)."""
import math
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / 'benchmarks'))

import gate_stability as gs  # noqa: E402
from zeroshot_calib_ros.core.lens.models import KannalaBrandtCamera  # noqa: E402
from zeroshot_calib_ros.core.zeroshot.spec import CameraSpec  # noqa: E402


def test_every_fov_of_the_spec_moves_by_the_delta_and_nothing_else():
    spec = CameraSpec(1920, 1080, hfov=120.0, vfov=70.0, dfov=140.0)
    for delta in (0.01, -0.01):
        moved = gs.perturb_spec(spec, delta)
        assert (moved.width, moved.height) == (1920, 1080)
        for name in ('hfov', 'vfov', 'dfov'):
            assert getattr(moved, name) == pytest.approx(getattr(spec, name) + delta, abs=1e-12)
        assert moved.circle_fov is None and moved.circle_diameter is None
    partial = gs.perturb_spec(CameraSpec(752, 480, vfov=142.3), 0.01)
    assert partial.vfov == pytest.approx(142.31) and partial.hfov is None and partial.dfov is None


def test_the_circle_fov_moves_but_not_the_circle_diameter():
    spec = CameraSpec(748, 480, circle_diameter=589.0, circle_fov=178.657)
    moved = gs.perturb_spec(spec, -0.01)
    assert moved.circle_fov == pytest.approx(178.647) and moved.circle_diameter == 589.0
    assert moved.given() == {}


def _textured(shape):
    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur(rng.integers(0, 256, shape[:2]).astype(np.uint8), (0, 0), 3.0)
    image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX)
    cv2.line(image, (10, 10), (shape[1] - 10, shape[0] - 20), 255, 2)
    return image if len(shape) == 2 else np.dstack([image, image // 2 + 60, image // 2 + 30])  # low chroma


@pytest.mark.parametrize('shape', [(120, 160), (120, 160, 3)])
def test_jpeg_95_keeps_shape_and_type_and_changes_the_pixels_a_little(shape):
    image = _textured(shape)
    out = gs.jpeg(image, 95)
    assert out.shape == image.shape and out.dtype == np.uint8
    diff = np.abs(out.astype(int) - image.astype(int))
    assert diff.max() > 0  # it is a perturbation
    assert diff.mean() < 3.0  # and a small one (quality 95)
    assert np.abs(gs.jpeg(image, 20).astype(int) - image.astype(int)).mean() > diff.mean()


def test_orders_leave_out_repeats():
    assert gs.orders(1) == {}
    assert gs.orders(2) == {'reversed': [1, 0]}
    assert gs.orders(4) == {'reversed': [3, 2, 1, 0], 'rotated': [1, 2, 3, 0]}
    assert list(gs.perturbation_names(1)) == ['fov+', 'fov-', 'jpeg']
    assert list(gs.perturbation_names(4).values()) == ['fov+0.01', 'fov-0.01', 'jpeg95', 'reversed', 'rotated']


def test_perturbed_inputs():
    spec = CameraSpec(160, 120, hfov=120.0)
    images = [np.full((120, 160), v, np.uint8) for v in (10, 20, 30)]
    s, ims, order = gs.perturbed(spec, images, gs.BASELINE)
    assert s is spec and order == [0, 1, 2] and all(a is b for a, b in zip(ims, images))
    s, ims, order = gs.perturbed(spec, images, 'reversed')
    assert s is spec and order == [2, 1, 0] and [int(i[0, 0]) for i in ims] == [30, 20, 10]
    s, ims, order = gs.perturbed(spec, images, 'rotated')
    assert [int(i[0, 0]) for i in ims] == [20, 30, 10]
    s, ims, _ = gs.perturbed(spec, images, 'fov-', delta_deg=0.5)
    assert s.hfov == pytest.approx(119.5) and all(a is b for a, b in zip(ims, images))
    s, ims, _ = gs.perturbed(spec, images, 'jpeg')
    assert s is spec and len(ims) == 3 and ims[0] is not images[0]


def _camera(fx=300.0, cx=160.0, k1=0.0):
    return KannalaBrandtCamera(fx, fx, cx, 120.0, 320, 240, np.array([k1, 0.0, 0.0, 0.0]))


def _run(key, accepted, camera, failure=''):
    import lens_profiles as lp
    return gs.Run('c', key, key, accepted=accepted, camera=camera, fitted=camera, failure=failure,
                  pixels=lp.pixel_grid(320, 240), scale=1920 / 320)


def test_change_is_zero_for_the_same_camera_and_ignores_a_rotation_but_not_a_shift():
    import lens_profiles as lp
    pixels = lp.pixel_grid(320, 240)
    base = _camera()
    assert gs.change_px(base, base, pixels, 6.0) == pytest.approx(0.0, abs=1e-6)
    assert gs.change_px(_camera(fx=303.0), base, pixels, 6.0) > 0.5
    assert math.isnan(gs.change_px(None, base, pixels, 6.0))


def test_flips_are_decisions_other_than_the_baseline_and_failed_runs_do_not_count():
    base = _camera()
    runs = [_run(gs.BASELINE, True, base), _run('fov+', True, base), _run('fov-', False, _camera(fx=303.0)),
            _run('jpeg', False, None, failure='ValueError: x'), _run('reversed', True, _camera(fx=300.5))]
    compared = gs.compare(runs)
    assert sorted(c.run.key for c in compared['c']) == ['fov+', 'fov-', 'reversed']
    flips = {c.run.key: c.flip for c in compared['c']}
    assert flips == {'fov+': False, 'fov-': True, 'reversed': False}
    t = gs.totals(compared)
    assert t['runs'] == 3 and t['flips'] == 1 and t['flip_share'] == pytest.approx(1 / 3)
    changes = {c.run.key: c.change_px for c in compared['c']}
    assert t['max_change_same_px'] == pytest.approx(changes['reversed'])
    assert t['max_change_flip_px'] == pytest.approx(changes['fov-'])
    assert t['cases_with_flip'] == 1
    # no baseline (or a failed one): the case is not compared
    assert gs.compare(runs[1:]) == {}
    assert math.isnan(gs.totals({})['flip_share'])


def test_the_report_counts_what_compare_counts():
    import argparse
    base = _camera()
    runs = [_run(gs.BASELINE, True, base), _run('fov+', False, _camera(fx=303.0))]
    case = gs.Case('c', 'lens', 'c', None, 320, 240, 1)
    args = argparse.Namespace(fov_delta=0.01, jpeg_quality=95, images=4, scene='room', views=4, image_width=960,
                              nuisances='none')
    text = gs.report([case], runs, 'benchmarks/gate_stability.py --x', 1.0, args)
    assert text.splitlines()[2].startswith('`benchmarks/gate_stability.py --x`')
    assert 'decision flips: 1 (100.0 %)' in text and '**no, FLIP**' in text and '### The flips' in text


def test_the_camera_cases_are_real_photos_cameras_with_its_image_selection():
    import real_photos as rp
    cases = gs.camera_cases(rp.PHOTOS, 4)
    cameras = rp.load_cameras()
    assert [c.name for c in cases] == [c.name for c in cameras]
    for case, camera in zip(cases, cameras):
        assert case.images == len(rp.evenly(camera.photos, 4)) and (case.width, case.height) == (camera.width,
                                                                                                  camera.height)
    left = next(c for c in cases if c.name == 'mynteye_s_jpl_left')  # in the repository
    spec, images, rays, pixels = left.load()
    assert spec == rp.spec_of(next(c for c in cameras if c.name == 'mynteye_s_jpl_left'))
    assert len(images) == 1 and images[0].ndim == 2 and len(rays) == len(pixels) > 100


def test_the_lens_cases_are_line_refinements_profiles_evenly_through_them(tmp_path):
    import argparse
    import lens_profiles as lp
    if not Path(lp.DEFAULT_CSV).is_file():
        pytest.skip(f'the shared data set is missing: {lp.DEFAULT_CSV} (set ZEROSHOT_SHARED_DATA)')
    import line_refinement as lr
    csv = tmp_path / 'profiles.csv'  # the first 400 profiles: all 5000 take 45 s to screen
    csv.write_text(''.join(Path(lp.DEFAULT_CSV).open().readlines()[:401]))
    args = argparse.Namespace(lenses=20, nuisances='none', scene='room', views=4, cache=None, image_width=960,
                              seed=0, csv=str(csv))
    cases = gs.lens_cases(args)
    chosen = lr.evenly(lr.wide_square_profiles(csv), 20)
    assert len(chosen) == 20
    assert [c.name for c in cases] == [f'lens{p.index}' for p, _ in chosen]
    assert all(c.width == 960 and c.images == 4 for c in cases)


def test_runs_pickled_by_the_script_run_as_main_are_read_back(tmp_path):
    """The script pickles its runs as ``__main__.Run``; --rows-from (and this test) read them."""
    import pickle
    import types
    main = types.ModuleType('__main__')

    class Run(gs.Run):
        pass
    Run.__module__, Run.__qualname__ = '__main__', 'Run'
    main.Run = Run
    saved = sys.modules['__main__']
    sys.modules['__main__'] = main
    try:
        (tmp_path / 'c__baseline.run.pkl').write_bytes(pickle.dumps(Run('c', gs.BASELINE, 'baseline', accepted=True)))
    finally:
        sys.modules['__main__'] = saved
    runs = gs.load_runs([str(tmp_path)])
    assert len(runs) == 1 and runs[0].case == 'c' and runs[0].accepted
