"""Camera presets: published spec sheets (resolution + FOVs) of common cameras, with sources.

The table is ``zeroshot_calib_ros/data/camera_presets.csv`` (installed with the package as
package data): one camera mode per row, ``name,width,height,hfov,vfov,dfov,circle_diameter,
circle_fov,description,source``, empty cells where the manufacturer publishes nothing, ``#``
lines are comments. Every row must name its source.

    from zeroshot_calib_ros.core.zeroshot.presets import get_preset
    solve_zero_shot(get_preset('gopro_hero9_wide'))

Names are matched case-insensitively, with '-' and ' ' read as '_'.
"""
from __future__ import annotations

import csv
import difflib
import io
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from typing import Dict, Optional

from .spec import CameraSpec, SpecError

PACKAGE = 'zeroshot_calib_ros'
PRESETS_FILE = ('data', 'camera_presets.csv')
"""Path of the table inside the package."""

COLUMNS = ('name', 'width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov',
           'description', 'source')
SPEC_FIELDS = ('width', 'height', 'hfov', 'vfov', 'dfov', 'circle_diameter', 'circle_fov')


class PresetError(ValueError):
    """The presets table is malformed (names the row and why)."""


@dataclass(frozen=True)
class Preset:
    name: str
    spec: CameraSpec
    description: str
    source: str

    @property
    def given(self) -> str:
        """Which FOVs the source gives, as 'h+v+d', 'd', 'h+v', 'circle' ... (the table's
        non-empty cells: nothing is derived or guessed)."""
        parts = [name[0] for name in self.spec.given()]
        if self.spec.circle_fov is not None:
            parts.append('circle')
        return '+'.join(parts)


def normalise_name(name: str) -> str:
    return str(name).strip().lower().replace('-', '_').replace(' ', '_')


def _cell_number(text: str, integer: bool = False):
    text = text.strip()
    if not text:
        return None
    return int(text) if integer else float(text)


def parse_presets(text: str, origin: str = PRESETS_FILE[-1]) -> Dict[str, Preset]:
    """Presets of a table in the format above; PresetError naming the line of any bad row."""
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith('#')]
    if not lines:
        raise PresetError(f'{origin}: no presets')
    header = next(csv.reader([lines[0][1]]))
    if tuple(h.strip() for h in header) != COLUMNS:
        raise PresetError(f'{origin}:{lines[0][0]}: header must be {",".join(COLUMNS)}')
    presets: Dict[str, Preset] = {}
    for number, line in lines[1:]:
        values = next(csv.reader(io.StringIO(line)))
        if len(values) != len(COLUMNS):
            raise PresetError(f'{origin}:{number}: {len(values)} cells, expected {len(COLUMNS)}')
        row = dict(zip(COLUMNS, values))
        name = normalise_name(row['name'])
        if not name:
            raise PresetError(f'{origin}:{number}: empty name')
        if name in presets:
            raise PresetError(f'{origin}:{number}: duplicate name {name!r}')
        if not row['source'].strip():
            raise PresetError(f'{origin}:{number}: {name} has no source')
        try:
            fields = {k: _cell_number(row[k], integer=k in ('width', 'height')) for k in SPEC_FIELDS}
            spec = CameraSpec(**fields)
        except (ValueError, SpecError) as exc:
            raise PresetError(f'{origin}:{number}: {name}: {exc}') from None
        presets[name] = Preset(name, spec, row['description'].strip(), row['source'].strip())
    return presets


@lru_cache(maxsize=1)
def _packaged() -> Dict[str, Preset]:
    resource = resources.files(PACKAGE).joinpath(*PRESETS_FILE)
    return parse_presets(resource.read_text(encoding='utf-8'), '/'.join(PRESETS_FILE))


def load_presets(path: Optional[str] = None) -> Dict[str, Preset]:
    """{name: Preset} of the packaged table (or of the CSV file at ``path``), in file order."""
    if path is None:
        return dict(_packaged())
    with open(path, encoding='utf-8') as f:
        return parse_presets(f.read(), str(path))


def get_preset_entry(name: str) -> Preset:
    """The Preset called ``name``; SpecError (field 'preset') listing close names otherwise."""
    presets = _packaged()
    key = normalise_name(name)
    if key in presets:
        return presets[key]
    close = difflib.get_close_matches(key, list(presets), n=5, cutoff=0.5)
    close += [n for n in presets if key and key in n and n not in close][:5 - len(close)]
    hint = f'did you mean {", ".join(close)}?' if close else 'no similar name'
    raise SpecError('preset', name, 'a preset name (`zeroshot-calib presets` lists them)',
                    f'unknown preset; {hint}')


def get_preset(name: str) -> CameraSpec:
    """The CameraSpec of preset ``name`` (see ``get_preset_entry`` for errors)."""
    return get_preset_entry(name).spec


def spec_with_preset(preset: Optional[str], **fields) -> CameraSpec:
    """The CameraSpec of ``preset`` (None or '': no preset) with every field given in ``fields``
    (not None) taking the place of the preset's: what `solve --preset` and the node's ``preset``
    parameter mean. A width and height of another aspect ratio than the preset's are refused
    (SpecError): its FOVs are those of its aspect ratio."""
    if not preset:
        return CameraSpec(**fields)  # CameraSpec names a missing or invalid field
    entry = get_preset_entry(preset)
    spec = entry.spec
    merged = {k: getattr(spec, k) for k in SPEC_FIELDS}
    merged.update({k: v for k, v in fields.items() if v is not None})
    result = CameraSpec(**merged)
    # the preset's FOVs belong to its aspect ratio: another one is another crop of the sensor
    if result.width * spec.height != result.height * spec.width:
        raise SpecError('width x height', f'{result.width}x{result.height}',
                        f'{spec.width}x{spec.height} or another size of that aspect ratio (scaled), or no preset',
                        f"preset {entry.name}'s fields of view are for {spec.width}x{spec.height}; another aspect "
                        'ratio is another crop of the sensor, with other FOVs')
    return result
