"""Spec sheets that contradict their image: FOVs in the wrong order are refused saying what looks
swapped; FOVs a camera can be solved from but does not show (no barrel root) are warned about,
naming the FOV given and the one the solved camera has, in the library (``warnings``), the CLI's
text and its --json (solve, --batch, rectify, refine, calibrate); honest specs (the paper's
Table 2, every preset, a sheet's 1-degree rounding) never warn. The node: test_node_params.py."""
import json
import math
import re

import cv2
import numpy as np
import pytest

from cli_run import run_main
from paper_table2 import load_table2
from zeroshot_calib_ros.core import CameraSpec, SpecError, solve_zero_shot
from zeroshot_calib_ros.core.lens.models import ZeroShotCamera
from zeroshot_calib_ros.core.lens.projections import PROJECTIONS
from zeroshot_calib_ros.core.zeroshot.consistency import EXTRA_FOV_WARNING_DEG
from zeroshot_calib_ros.core.zeroshot.presets import load_presets
from zeroshot_calib_ros.core.zeroshot.spec import FOV_TOLERANCE_DEG

SWAPPED = {  # spec -> (field, what the error says)
    (1080, 1920, 118, 69): ('width, height', 'width and height look swapped'),
    (1920, 1080, 69, 118): ('vfov', 'hfov and vfov look swapped'),
}
CONTRADICTORY = {  # spec -> (hfov, vfov) of the solved camera, as printed (solve's FOV line)
    (1920, 1080, 118, 117): (129.4, 99.9),
    (1920, 1080, 118, 100): (123.6, 92.7),
}
ALL_PROJECTIONS = ('auto', *PROJECTIONS, 'wide')


def spec_args(spec):
    w, h, hfov, vfov = spec
    return ['--width', str(w), '--height', str(h), '--hfov', f'{hfov:g}', '--vfov', f'{vfov:g}']


# -- the library ---------------------------------------------------------------------------------

@pytest.mark.parametrize('spec', list(SWAPPED), ids=['width-height', 'hfov-vfov'])
def test_swapped_fovs_or_sides_are_refused_in_one_line_saying_swapped(spec):
    field, words = SWAPPED[spec]
    with pytest.raises(SpecError) as err:
        CameraSpec(*spec)
    text = str(err.value)
    assert err.value.field == field and words in text and 'allowed: ' in text and '\n' not in text
    assert err.value.field == field
    if field == 'width, height':  # what it allows: the same size turned, or the FOVs swapped
        assert f'allowed: {spec[1]}x{spec[0]}, or vfov greater than hfov' in text, text
    # the other orientation of the same camera is fine: the FOVs follow the sides
    w, h, hfov, vfov = spec
    assert CameraSpec(h, w, hfov, vfov) and CameraSpec(w, h, vfov, hfov)


def test_equal_fovs_on_a_non_square_image_are_not_refused():
    """A sheet's rounding can make hfov and vfov of a nearly square image equal (never reverse
    their order: rounding is monotonic), so equal passes the order check."""
    solution = solve_zero_shot(CameraSpec(1024, 1000, 100, 100))
    assert solution.warnings == []


@pytest.mark.parametrize('spec', list(CONTRADICTORY), ids=['118x117', '118x100'])
@pytest.mark.parametrize('projection', ['auto', 'equidistant', 'wide'])
def test_fovs_the_solved_camera_does_not_show_are_warned_naming_both_values(spec, projection):
    solution = solve_zero_shot(CameraSpec(*spec), projection)
    hfov, vfov = CONTRADICTORY[spec]
    assert not solution.root_found and len(solution.warnings) == 1
    warning = solution.warnings[0]
    assert f'hfov: given {spec[2]:g} deg, the solved camera has {hfov:.1f} deg' in warning
    assert f'vfov: given {spec[3]:g} deg, the solved camera has {vfov:.1f} deg' in warning
    assert '1920x1080' in warning and 'pincushion' in warning and '\n' not in warning
    fovs = solution.predicted_fovs()
    assert (round(fovs['hfov'], 1), round(fovs['vfov'], 1)) == (hfov, vfov)
    # the bound named: the widest vfov beside hfov 118 without pincushion, a pinhole's
    bound = 2 * math.degrees(math.atan(math.tan(math.radians(59)) * 1080 / 1920))
    assert f'has vfov at most {bound:.1f} deg' in warning


def test_the_papers_table2_specs_and_every_preset_never_warn():
    specs = {row['camera']: CameraSpec(int(row['width']), int(row['height']), row['hfov'], row['vfov'])
             for row in load_table2()}
    specs.update({name: preset.spec for name, preset in load_presets().items()})
    for name, spec in specs.items():
        for projection in ALL_PROJECTIONS:
            assert solve_zero_shot(spec, projection).warnings == [], (name, projection)


def _barrel_cameras():
    """Distortion-free and barrel-distorted equidistant cameras of several sizes and FOVs."""
    for w, h in ((1920, 1080), (1280, 800), (1280, 960), (848, 800), (4608, 2592), (2560, 1080)):
        corner = math.hypot(w, h) / 2
        for hfov in (40, 70, 100, 130, 160):
            for share in (0.0, 0.1, 0.3, 0.6, 0.9):
                omega = share * PROJECTIONS['equidistant'].rho_max / corner
                # f that gives this hfov: bisection on the monotonic hfov(f)
                lo, hi = 1.0, 1e5
                for _ in range(100):
                    f = math.sqrt(lo * hi)
                    if ZeroShotCamera(f, w / 2, h / 2, w, h, omega).fields_of_view()['hfov'] > hfov:
                        lo = f
                    else:
                        hi = f
                camera = ZeroShotCamera(f, w / 2, h / 2, w, h, omega)
                if camera.fields_of_view()['dfov'] < 178:
                    yield w, h, camera.fields_of_view()


def test_a_spec_sheets_rounding_never_warns():
    """Each FOV off by up to half a degree (a sheet printing whole degrees), in every direction:
    the FOVs stay within the default tolerance of the solved camera's, so no warning."""
    count = 0
    for w, h, fovs in _barrel_cameras():
        for dh in (-0.5, 0.0, 0.5):
            for dv in (-0.5, 0.0, 0.5):
                spec = CameraSpec(w, h, fovs['hfov'] + dh * 0.999, fovs['vfov'] + dv * 0.999)
                assert solve_zero_shot(spec).warnings == [], spec
                count += 1
    assert count > 500


def test_a_spec_the_camera_reproduces_exactly_never_warns_even_at_a_tight_tolerance():
    for w, h, fovs in _barrel_cameras():
        spec = CameraSpec(w, h, fovs['hfov'], fovs['vfov'])
        assert solve_zero_shot(spec, fov_tolerance=1e-6).warnings == [], spec


def test_fov_tolerance_sets_the_threshold_and_is_checked():
    spec = CameraSpec(1920, 1080, 100, 69)  # no barrel root: misses by 0.7 degree
    assert FOV_TOLERANCE_DEG == 1.0
    assert solve_zero_shot(spec).warnings == []
    assert 'tolerance 0.5 deg' in solve_zero_shot(spec, fov_tolerance=0.5).warnings[0]
    assert solve_zero_shot(CameraSpec(1920, 1080, 118, 100), fov_tolerance=10).warnings == []
    for bad in (0, -1, math.nan, math.inf, True, 'one'):
        with pytest.raises(SpecError) as err:
            solve_zero_shot(spec, fov_tolerance=bad)
        assert err.value.field == 'fov_tolerance' and 'allowed: ' in str(err.value)


def test_by_default_a_fov_missed_by_more_than_one_degree_is_warned_about():
    """1920 x 1080, hfov 100: a lens without pincushion has vfov at most 67.7 deg; vfov 71 is 3.3
    beyond, which the camera without a barrel root splits between the two FOVs (each missed by
    about half of it, more than 1 and less than 2 degrees): a warning at the default tolerance,
    none at 2 degrees."""
    spec = CameraSpec(1920, 1080, 100, 71)
    fovs = solve_zero_shot(spec).predicted_fovs()
    assert 1 < abs(fovs['hfov'] - 100) < 2 and 1 < abs(fovs['vfov'] - 71) < 2
    assert len(solve_zero_shot(spec).warnings) == 1 and 'tolerance 1 deg' in solve_zero_shot(spec).warnings[0]
    assert solve_zero_shot(spec, fov_tolerance=2).warnings == []


def test_a_tolerance_wider_than_15_degrees_holds_for_the_diagonal_beside_the_pair_too():
    """The diagonal beside hfov + vfov is warned about beyond max(tolerance, 15 deg): 118 x 69 x 152
    on 16:9 (the camera has a dfov of 135.7: 16.3 off) warns at the default tolerance and not at
    --fov-tolerance 20."""
    spec = CameraSpec(1920, 1080, 118, 69, 152)
    assert len(solve_zero_shot(spec).warnings) == 1 and 'dfov: given 152 deg' in solve_zero_shot(spec).warnings[0]
    assert solve_zero_shot(spec, fov_tolerance=20).warnings == []


def test_a_diagonal_beside_hfov_and_vfov_is_warned_about_only_when_far_off():
    """dfov beside hfov + vfov only chooses the projection; sheets quote it loosely (the Raspberry
    Pi Camera Module 3 Wide's 120 misses by 9.1 degrees), so only a miss beyond
    EXTRA_FOV_WARNING_DEG warns."""
    assert EXTRA_FOV_WARNING_DEG == 15.0
    solution = solve_zero_shot(CameraSpec(4608, 2592, 102, 67, 120))
    assert solution.warnings == [] and -10 < solution.dfov_residuals[solution.projection.name] < -9
    assert solve_zero_shot(CameraSpec(1920, 1080, 118, 69, 140)).warnings == []
    solution = solve_zero_shot(CameraSpec(1920, 1080, 118, 69, 170))
    assert len(solution.warnings) == 1 and 'dfov: given 170 deg, the solved camera has 135.7 deg' in \
        solution.warnings[0] and 'hfov: given' not in solution.warnings[0]


def test_the_wide_model_and_a_circle_are_checked_too():
    # a circular fisheye alone: one constraint, always met
    assert solve_zero_shot(CameraSpec(1920, 1080, circle_diameter=1000, circle_fov=200)).warnings == []
    # beside an hfov that contradicts it by far (the circle and hfov are the pair the wide model meets)
    ok = solve_zero_shot(CameraSpec(1920, 1080, hfov=200, circle_diameter=1000, circle_fov=190))
    assert ok.warnings == []
    solution = solve_zero_shot(CameraSpec(1920, 1080, 150, 149), 'wide')
    assert solution.warnings and 'vfov: given 149 deg' in solution.warnings[0]


# -- the CLI -------------------------------------------------------------------------------------

@pytest.mark.parametrize('spec', list(SWAPPED), ids=['width-height', 'hfov-vfov'])
@pytest.mark.parametrize('json_flag', [[], ['--json']], ids=['text', 'json'])
def test_cli_solve_refuses_swapped_specs_in_one_line(spec, json_flag, capsys):
    status, out, err = run_main(['solve', *spec_args(spec), *json_flag], capsys)
    field, words = SWAPPED[spec]
    assert status == 2 and out == '' and len(err) == 1, err
    assert err[0].startswith(f'zeroshot-calib: error: {field} = ') and words in err[0] and 'allowed: ' in err[0]


@pytest.mark.parametrize('spec', list(CONTRADICTORY), ids=['118x117', '118x100'])
def test_cli_solve_warns_in_its_text_and_its_json(spec, capsys):
    hfov, vfov = CONTRADICTORY[spec]
    wanted = f'vfov: given {spec[3]:g} deg, the solved camera has {vfov:.1f} deg'
    status, out, err = run_main(['solve', *spec_args(spec)], capsys)
    shown = re.search(r'^FOV       h ([0-9.]+), v ([0-9.]+)', out, re.M)
    assert status == 0 and (round(float(shown[1]), 1), round(float(shown[2]), 1)) == (hfov, vfov), out
    warned = [line for line in err if wanted in line]
    assert len(warned) == 1 and warned[0].startswith('zeroshot-calib: warning: the FOVs do not fit'), err
    status, out, err = run_main(['solve', *spec_args(spec), '--json'], capsys)
    record = json.loads(out)
    assert status == 0 and sum(wanted in w for w in record['warning']) == 1, record['warning']
    assert any(wanted in line for line in err)
    # a wider tolerance: no warning
    status, out, err = run_main(['solve', *spec_args(spec), '--json', '--fov-tolerance', '20'], capsys)
    assert not any('do not fit' in w for w in json.loads(out)['warning'])
    assert not any('do not fit' in line for line in err)


def test_cli_solve_of_honest_specs_and_presets_has_no_spec_warning(capsys):
    for name in load_presets():
        status, out, err = run_main(['solve', '--preset', name, '--json'], capsys)
        assert status == 0 and not any('do not fit' in w or 'given' in w for w in json.loads(out)['warning']), name
    for row in load_table2():
        args = ['--width', str(int(row['width'])), '--height', str(int(row['height'])), '--hfov', str(row['hfov'])]
        args += ['--vfov', str(row['vfov'])] if row['vfov'] else []
        status, out, err = run_main(['solve', *args, '--json'], capsys)
        assert status == 0 and not any('given' in w for w in json.loads(out)['warning']), row['camera']


def test_cli_batch_warns_per_row_and_refuses_swapped_rows(tmp_path, capsys):
    path = tmp_path / 'cameras.csv'
    path.write_text('hero9,1920,1080,118,69,\nodd,1920,1080,118,117,\nturned,1080,1920,118,69,\n')
    status, out, err = run_main(['solve', '--batch', str(path)], capsys)
    records = [json.loads(line) for line in out.splitlines()]
    assert status == 1 and [r['name'] for r in records] == ['hero9', 'odd', 'turned']
    assert records[0]['warning'] == []
    assert any('vfov: given 117 deg, the solved camera has 99.9 deg' in w for w in records[1]['warning'])
    assert 'width and height look swapped' in records[2]['error']
    assert any(line.startswith('zeroshot-calib: warning: row 2 (odd): the FOVs do not fit') for line in err), err


def test_cli_rectify_warns_and_refuses_swapped(tmp_path, capsys):
    image = tmp_path / 'in.png'
    cv2.imwrite(str(image), np.full((108, 192), 128, np.uint8))
    status, _, err = run_main(['rectify', str(image), '-o', str(tmp_path / 'out.png'), '--hfov', '118',
                               '--vfov', '117'], capsys)
    assert status == 0 and (tmp_path / 'out.png').is_file()
    assert any('zeroshot-calib: warning: the FOVs do not fit a 192x108 image' in line and
               'vfov: given 117 deg, the solved camera has 99.9 deg' in line for line in err), err
    status, _, err = run_main(['rectify', str(image), '-o', str(tmp_path / 'out.png'), '--hfov', '118',
                               '--vfov', '69'], capsys)
    assert status == 0 and err == []
    status, _, err = run_main(['rectify', str(image), '-o', str(tmp_path / 'out.png'), '--hfov', '69',
                               '--vfov', '118'], capsys)
    assert status == 2 and len(err) == 1 and 'hfov and vfov look swapped' in err[0]


def test_cli_refine_warns_in_its_text_and_json(tmp_path, capsys):
    image = tmp_path / 'blank.png'
    cv2.imwrite(str(image), np.zeros((180, 320), np.uint8))  # no lines: the zero-shot camera is kept
    status, out, err = run_main(['refine', str(image), '--hfov', '118', '--vfov', '117', '--json'], capsys)
    record = json.loads(out)
    assert status == 3 and record['refinement']['accepted'] is False  # 3: ran, not refined (documented)
    assert any('vfov: given 117 deg, the solved camera has 99.9 deg' in w for w in record['warning']), record
    assert any('warning: the FOVs do not fit a 320x180 image' in line for line in err), err
    status, out, err = run_main(['refine', str(image), '--hfov', '118', '--vfov', '69', '--json'], capsys)
    assert status == 3 and not any('given' in w for w in json.loads(out)['warning'])
    # at --fov-tolerance 20 (118 / 117 are missed by 11.4 and 17.1 degrees): no warning
    status, out, err = run_main(['refine', str(image), '--hfov', '118', '--vfov', '117', '--fov-tolerance', '20',
                                 '--json'], capsys)
    assert status == 3 and not any('do not fit' in w for w in json.loads(out)['warning'])
    assert not any('do not fit' in line for line in err), err


def status_of(out):
    """The documented exit status of a `calibrate --json` printing ``out``: 3 when the board fit
    was not adopted (`accepted: false`), else 0."""
    return 3 if json.loads(out).get('accepted') is False else 0


def test_cli_calibrate_warns_about_the_spec(tmp_path, capsys):
    """calibrate warns of FOVs that do not fit the image, with the spec as evidence or as the start,
    not of honest ones, and not within --fov-tolerance. On one board view: the warning is about the
    spec alone, and each run's board fit costs in proportion to its views."""
    from test_board_fit import board_views
    truth = ZeroShotCamera(300.0, 320, 240, 640, 480, 1.0 / 400)
    corners, _ = board_views(truth, 1, seed=5, noise=0.2)
    corners.save(str(tmp_path / 'corners.json'))
    fovs = truth.fields_of_view()
    honest = ['--hfov', f"{fovs['hfov']:.0f}", '--vfov', f"{fovs['vfov']:.0f}"]
    odd = ['--hfov', f"{fovs['hfov']:.0f}", '--vfov', f"{fovs['hfov'] - 1:.0f}"]
    for spec_as in ('evidence', 'start'):
        status, out, err = run_main(['calibrate', '--corners', str(tmp_path / 'corners.json'), *odd,
                                     '--spec-as', spec_as, '--json'], capsys)
        assert status == status_of(out), err
        assert any('the FOVs do not fit a 640x480 image' in w for w in json.loads(out)['warning']), spec_as
        assert any('zeroshot-calib: warning: the FOVs do not fit' in line for line in err), err
        status, out, err = run_main(['calibrate', '--corners', str(tmp_path / 'corners.json'), *honest,
                                     '--spec-as', spec_as, '--json'], capsys)
        assert status == status_of(out) and not any('do not fit' in w for w in json.loads(out)['warning']), spec_as
    # the same odd spec at a --fov-tolerance wider than its miss: no warning about it
    missed = solve_zero_shot(CameraSpec(640, 480, float(odd[1]), float(odd[3]))).predicted_fovs()
    tolerance = 1 + max(abs(missed['hfov'] - float(odd[1])), abs(missed['vfov'] - float(odd[3])))
    status, out, err = run_main(['calibrate', '--corners', str(tmp_path / 'corners.json'), *odd,
                                 '--fov-tolerance', f'{tolerance:.1f}', '--json'], capsys)
    assert status == status_of(out) and not any('do not fit' in w for w in json.loads(out)['warning'])
    assert not any('do not fit' in line for line in err), err


def test_the_documented_consistency_lines_are_what_solve_prints(capsys):
    """docs/cli.md's examples of the swapped-FOV error and the FOVs-do-not-fit warning are what
    `solve` prints for the commands they name."""
    from doc_pages import all_pages
    documented = re.findall(r'e\.g\. for\s+`solve ([^`]*)`:\s*`(zeroshot-calib: (error|warning): [^`]*)`',
                            all_pages())
    assert any('look swapped' in line for _, line, _ in documented)
    assert any('the FOVs do not fit' in line for _, line, _ in documented)
    for command, line, kind in documented:
        status, _, err = run_main(['solve', *command.split()], capsys)
        assert status == (2 if kind == 'error' else 0) and err == [line], (command, err)


def test_cli_rectify_says_what_one_fov_assumed_and_takes_the_fov_tolerance(tmp_path, capsys):
    """rectify with one FOV rectifies through the lens shape of real lenses of that FOV and says
    so (as solve does); --fov-tolerance sets its consistency threshold as in solve."""
    image = tmp_path / 'in.png'
    cv2.imwrite(str(image), np.full((108, 192), 128, np.uint8))
    status, _, err = run_main(['rectify', str(image), '-o', str(tmp_path / 'out.png'), '--hfov', '170'], capsys)
    assert status == 0 and (tmp_path / 'out.png').is_file()
    assert len(err) == 1 and err[0].startswith('zeroshot-calib: warning: one FOV (hfov 170 deg): lens shape from'), err
    for tolerance, warned in (('1', True), ('20', False)):
        status, _, err = run_main(['rectify', str(image), '-o', str(tmp_path / 'out.png'), '--hfov', '118',
                                   '--vfov', '100', '--fov-tolerance', tolerance], capsys)
        assert status == 0 and any('vfov: given 100 deg' in line for line in err) == warned, (tolerance, err)
