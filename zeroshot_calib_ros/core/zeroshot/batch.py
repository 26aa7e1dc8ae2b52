"""A CSV file of cameras, one spec sheet a row (`zeroshot-calib solve --batch`): its rows, each
row's name and CameraSpec, and the file and camera names derived from a row's name. Every refusal
is a ValueError naming the line, the column or the field."""
from __future__ import annotations

import csv
import dataclasses
import difflib
import hashlib
import re
from typing import Union

from ..file_input import read_capped
from .numbers import is_number, parse_number, parse_whole_number
from .spec import CameraSpec, SpecError

BATCH_COLUMNS = ('name', 'width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov')
BATCH_POSITIONAL = BATCH_COLUMNS[:6]
"""The columns of a CSV without a header row, in this order."""
YAML_NAME_BYTES = 90
"""Longest file name (UTF-8 bytes, before a hash suffix and '.yaml') derived from a row name."""
MAX_BATCH_BYTES = 16 << 20
"""Largest --batch file read (a camera a row: about 100,000 cameras)."""
_HEADER_CELL = re.compile(r'[A-Za-z_][A-Za-z0-9_ -]*\Z')
_CONTROL = re.compile('[\x00-\x08\x0b-\x1f\x7f-\x9f\u2028\u2029]')
"""Characters refused in a CSV cell: control characters and line / paragraph separators (a quoted
cell may hold a newline or a tab)."""


class BatchError(ValueError):
    """A batch file, or one of its rows, that gives no camera; the message names where and why."""


def _is_header(cells) -> bool:
    """A first row is the header when none of its cells is a number and they read as names."""
    names = [c.strip() for c in cells if c.strip()]
    if not names or any(is_number(c) for c in names) or not all(_HEADER_CELL.match(c) for c in names):
        return False
    return len(names) >= 2 or names[0].lower() in BATCH_COLUMNS


def header_columns(cells, where: str) -> list:
    """The column names of a header row (lower case); BatchError for an empty, unknown or
    repeated column (``where``: the file and line, for the message)."""
    columns = [c.strip().lower() for c in cells]
    allowed = f'allowed: {", ".join(BATCH_COLUMNS)}'
    for i, column in enumerate(columns, start=1):
        if not column:
            raise BatchError(f'{where}: header column {i} is empty: {allowed}')
        if column not in BATCH_COLUMNS:
            close = difflib.get_close_matches(column, BATCH_COLUMNS, n=1)
            hint = f' (did you mean {close[0]}?)' if close else ''
            raise BatchError(f'{where}: header column {cells[i - 1].strip()!r} is unknown{hint}: {allowed} '
                             '(a first row without numbers is read as the header)')
        if columns.index(column) != i - 1:
            raise BatchError(f'{where}: header column {column!r} appears twice: {allowed}, each once')
    return columns


def csv_records(text: str) -> list:
    """[(line number, cells or csv.Error)] of CSV text: records end only at \\n or \\r\\n outside
    quotes (a quoted cell may span lines, as spreadsheets write it); blank and # lines skipped."""
    lines = text.split('\n')
    if lines and lines[-1] == '':
        lines.pop()
    lines = [line[:-1] if line.endswith('\r') else line for line in lines]
    records, i = [], 0
    while i < len(lines):
        start, chunk = i + 1, [lines[i]]
        i += 1
        if not chunk[0].strip() or chunk[0].lstrip().startswith('#'):
            continue
        while sum(part.count('"') for part in chunk) % 2 and i < len(lines):
            chunk.append(lines[i])
            i += 1
        try:
            cells = next(csv.reader(['\n'.join(chunk)], strict=True))
            bad = next((c for c in cells if _CONTROL.search(c)), None)
            if bad is not None:
                char = _CONTROL.search(bad).group()
                raise csv.Error(f'a cell holds the control character U+{ord(char):04X} (lines end only at '
                                '\\n or \\r\\n): allowed: printable text')
        except csv.Error as exc:
            where = f'line {start}' if len(chunk) == 1 else f'lines {start}-{start + len(chunk) - 1}'
            cells = csv.Error(f'{where}: {exc}')
        records.append((start, cells))
    return records


@dataclasses.dataclass(frozen=True)
class BatchRow:
    """One camera row: its number among the camera rows (from 1), the file line it starts on, its
    cells (or the csv.Error that made it unreadable) and the file's columns."""

    number: int
    line: int
    cells: Union[list, csv.Error]
    columns: tuple

    def _fields(self) -> dict:
        """The cells by column; BatchError for an unreadable row or one with too many cells."""
        if isinstance(self.cells, Exception):
            raise BatchError(f'not a CSV row: {self.cells}')
        if len(self.cells) > len(self.columns):
            origin = 'header' if self.columns != BATCH_POSITIONAL else 'file'
            raise BatchError(f'{len(self.cells)} cells, but the {origin} has {len(self.columns)} columns: '
                             f'allowed: at most {len(self.columns)} cells ({",".join(self.columns)})')
        return dict(zip(self.columns, self.cells))

    @property
    def name(self) -> str:
        """The name cell, or camera_<number> when it is empty or the row has no usable cells."""
        try:
            return (self._fields().get('name') or '').strip() or f'camera_{self.number}'
        except BatchError:
            return f'camera_{self.number}'

    def spec(self) -> CameraSpec:
        """The row's CameraSpec (empty cells: not given); BatchError for an unreadable row,
        SpecError naming the field for a cell that is not a number or out of range."""
        fields = self._fields()

        def cell(key, parse, allowed):
            value = (fields.get(key) or '').strip()
            if not value:
                return None
            try:
                return parse(value)
            except ValueError:
                raise SpecError(key, value, allowed) from None
        sides = {k: cell(k, parse_whole_number, 'a whole number of pixels') for k in ('width', 'height')}
        return CameraSpec(**sides, **{k: cell(k, parse_number, 'a number') for k in BATCH_COLUMNS[3:]})


def parse_batch(text: str, source: str) -> list:
    """The BatchRows of CSV ``text`` (``source``: the file, for the messages): a first row without
    numbers is the header naming the columns, else the columns are BATCH_POSITIONAL; BatchError
    when the header is bad or there is no camera row."""
    records = csv_records(text)
    columns = BATCH_POSITIONAL
    if records and not isinstance(records[0][1], Exception) and _is_header(records[0][1]):
        columns = tuple(header_columns(records[0][1], f'{source} line {records[0][0]}'))
        records = records[1:]
    if not records:
        raise BatchError(f'{source} has no camera rows: allowed: one camera a row, '
                         f'{",".join(BATCH_POSITIONAL)} (a header row, # comments and blank lines optional)')
    return [BatchRow(number, line, cells, columns) for number, (line, cells) in enumerate(records, start=1)]


def read_batch(path: str) -> list:
    """The BatchRows of the CSV file ``path`` (at most MAX_BATCH_BYTES, UTF-8 with or without a
    byte-order mark); InputFileError / BatchError naming the file otherwise."""
    data = read_capped(path, MAX_BATCH_BYTES, 'a CSV file, one camera a row')
    try:
        text = data.decode('utf-8-sig')
    except UnicodeDecodeError as exc:
        raise BatchError(f'cannot read {path}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset '
                         f'{exc.start}): allowed: a UTF-8 CSV file') from None
    return parse_batch(text, path)


def camera_name_of(row_name: str) -> str:
    """A row's name as a camera_name (camera_info_manager allows letters, digits and _ only:
    'hero9-wide' is written as hero9_wide), so that any row name gives a loadable file."""
    name = re.sub(r'[^A-Za-z0-9_]', '_', row_name)[:200]
    return name if name.strip('_') else 'camera'


def yaml_file_name(name: str):
    """A file name for ``name``: letters, digits, '-', '_' and '.' kept, anything else (path
    separators included) '_', no leading '.', at most YAML_NAME_BYTES bytes (longer names are cut
    and get a hash of the whole name); None if nothing is left."""
    safe = ''.join(ch if ch.isalnum() or ch in '-_.' else '_' for ch in name).lstrip('.')
    if len(safe.encode('utf-8')) > YAML_NAME_BYTES:
        cut = safe.encode('utf-8')[:YAML_NAME_BYTES].decode('utf-8', 'ignore')
        safe = f"{cut}-{hashlib.sha1(name.encode('utf-8')).hexdigest()[:8]}"
    return f'{safe}.yaml' if safe.strip('_') else None
