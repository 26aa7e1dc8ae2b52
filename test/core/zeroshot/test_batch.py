"""core/zeroshot/batch.py and numbers.py: a CSV of cameras read into names and specs without the
command line, and the numbers a user types (ASCII notation only)."""
import csv
import math

import pytest

from zeroshot_calib_ros.core.file_input import InputFileError
from zeroshot_calib_ros.core.zeroshot.batch import (BatchError, camera_name_of, csv_records, parse_batch, read_batch,
                                                    yaml_file_name)
from zeroshot_calib_ros.core.zeroshot.numbers import parse_integer, parse_number, parse_whole_number
from zeroshot_calib_ros.core.zeroshot.spec import SpecError


def test_a_header_row_names_the_columns_in_any_order_and_case():
    row, = parse_batch('Name,HFOV,width,Height,circle_diameter,circle_fov\nfront,,1920,1080,1000,200\n', 'c.csv')
    spec = row.spec()
    assert row.name == 'front'
    assert (spec.width, spec.height, spec.hfov) == (1920, 1080, None)
    assert (spec.circle_diameter, spec.circle_fov) == (1000, 200)


def test_without_a_header_the_columns_are_name_width_height_hfov_vfov_dfov():
    row, = parse_batch('cam,1920,1080,118,69,\n', 'c.csv')
    spec = row.spec()
    assert (row.name, spec.width, spec.height, spec.hfov, spec.vfov, spec.dfov) == ('cam', 1920, 1080, 118, 69, None)


def test_comments_and_blank_lines_are_skipped_and_rows_keep_their_file_lines():
    text = '# cameras\n\nname,width,height,hfov\r\n\na,640,480,90\n# b is off\nc,800,600,100\n'
    rows = parse_batch(text, 'c.csv')
    assert [(r.number, r.line, r.name) for r in rows] == [(1, 5, 'a'), (2, 7, 'c')]


def test_a_quoted_cell_may_span_lines_as_spreadsheets_write_it():
    records = csv_records('"front\nleft",640,480,90\nrear,640,480,90\n')
    assert records == [(1, ['front\nleft', '640', '480', '90']), (3, ['rear', '640', '480', '90'])]


def test_a_misspelt_header_column_names_it_and_the_column_meant():
    with pytest.raises(BatchError, match=r"c.csv line 1: header column 'hfvo' is unknown \(did you mean hfov\?\)"):
        parse_batch('name,width,height,hfvo\nw1,1920,1080,118\n', 'c.csv')


def test_a_repeated_or_empty_header_column_is_refused():
    with pytest.raises(BatchError, match="'width' appears twice"):
        parse_batch('name,width,Width\na,1,2\n', 'c.csv')
    with pytest.raises(BatchError, match='header column 2 is empty'):
        parse_batch('name,,height\na,1,2\n', 'c.csv')


@pytest.mark.parametrize('text', ['', '# only a comment\n\n', 'name,width,height\n'])
def test_a_file_without_camera_rows_is_refused_naming_it(text):
    with pytest.raises(BatchError, match='c.csv has no camera rows'):
        parse_batch(text, 'c.csv')


def test_a_bad_cell_names_the_field_and_the_value():
    row, = parse_batch('a,wide,1080,118\n', 'c.csv')
    with pytest.raises(SpecError) as error:
        row.spec()
    assert 'width' in str(error.value) and 'wide' in str(error.value)
    assert row.name == 'a'  # the record of the failed row still carries its name


def test_an_integral_float_side_is_a_whole_number_and_a_fraction_is_refused():
    assert parse_batch('a,1920.0,1080,118\n', 'c.csv')[0].spec().width == 1920
    with pytest.raises(SpecError, match='width'):
        parse_batch('a,1920.5,1080,118\n', 'c.csv')[0].spec()


def test_a_row_with_more_cells_than_columns_is_refused_and_named_by_its_number():
    rows = parse_batch('name,width,height,hfov\nok,640,480,90\nx,640,480,90,69\n', 'c.csv')
    assert rows[0].spec().width == 640
    with pytest.raises(BatchError, match='5 cells, but the header has 4 columns'):
        rows[1].spec()
    assert rows[1].name == 'camera_2'


def test_a_control_character_makes_only_its_row_unreadable():
    rows = parse_batch('a,640,480,90\nb\x0b,640,480,90\nc,640,480,90\n', 'c.csv')
    with pytest.raises(BatchError, match=r'not a CSV row: line 2: .*U\+000B'):
        rows[1].spec()
    assert isinstance(rows[1].cells, csv.Error) and rows[1].name == 'camera_2'
    assert [rows[0].spec().width, rows[2].spec().width] == [640, 640]


def test_read_batch_takes_a_byte_order_mark_and_refuses_other_encodings(tmp_path):
    path = tmp_path / 'c.csv'
    path.write_bytes(b'\xef\xbb\xbfname,width,height,hfov\nw1,1920,1080,118\n')
    row, = read_batch(str(path))
    assert (row.name, row.spec().hfov) == ('w1', 118)
    path.write_bytes('w1,1920,1080,118 \xb0\n'.encode('latin-1'))
    with pytest.raises(BatchError, match=rf'cannot read {path}: not UTF-8 text \(byte 0xb0 at offset 17\)'):
        read_batch(str(path))
    with pytest.raises(InputFileError):
        read_batch(str(tmp_path / 'missing.csv'))


def test_camera_names_keep_letters_digits_and_underscores_only():
    assert camera_name_of('hero9-wide') == 'hero9_wide'
    assert camera_name_of('front left') == 'front_left'
    assert camera_name_of('---') == 'camera'


def test_yaml_file_names_stay_inside_the_directory_and_long_names_stay_distinct():
    assert yaml_file_name('hero9-wide.v2') == 'hero9-wide.v2.yaml'
    for name in ('../etc/passwd', '/abs/path', '..'):
        file_name = yaml_file_name(name)
        assert file_name is None or ('/' not in file_name and not file_name.startswith('.')), name
    assert yaml_file_name('///') is None
    first, second = yaml_file_name('x' * 200 + 'a'), yaml_file_name('x' * 200 + 'b')
    assert first != second and len(first.encode('utf-8')) <= 90 + len('-12345678.yaml')


@pytest.mark.parametrize('text', ['1_18', '\uff11\uff11\uff18', '\u0661\u0661\u0668', ' 118', '118 ', '', '0x10'])
def test_numbers_are_ascii_decimal_only(text):
    with pytest.raises(ValueError):
        parse_number(text)


def test_numbers_take_decimal_and_exponent_notation_and_nan_or_inf_for_the_spec_to_refuse():
    assert parse_number('1e2') == 100.0 and parse_number('-.5') == -0.5
    assert math.isnan(parse_number('nan')) and parse_number('-Infinity') == -math.inf
    assert parse_whole_number('1920') == 1920 and type(parse_whole_number('1920.0')) is int
    assert parse_whole_number('1920.5') == 1920.5
    assert parse_integer('+3') == 3
    with pytest.raises(ValueError):
        parse_integer('1.0')
