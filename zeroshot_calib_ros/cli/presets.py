"""``zeroshot-calib presets``: the camera presets (published spec sheets), as a table or JSON."""
from __future__ import annotations

import json

from ..core.zeroshot.presets import load_presets


def add_parser(subparsers):
    presets = subparsers.add_parser('presets', help='list the camera presets (published spec sheets)')
    presets.add_argument('--json', action='store_true', help='print one JSON array')
    presets.set_defaults(run=run)


def run(args):
    presets = load_presets()
    records = [{'name': p.name, 'width': p.spec.width, 'height': p.spec.height, 'hfov': p.spec.hfov,
                'vfov': p.spec.vfov, 'dfov': p.spec.dfov, 'circle_diameter': p.spec.circle_diameter,
                'circle_fov': p.spec.circle_fov, 'given': p.given, 'description': p.description,
                'source': p.source}
               for p in presets.values()]
    if args.json:
        print(json.dumps(records))
        return 0

    def deg(value):
        return '-' if value is None else f'{value:g}'
    rows = [('name', 'resolution', 'hfov', 'vfov', 'dfov', 'circle', 'given', 'source')]
    for r in records:
        circle = '-' if r['circle_diameter'] is None else f"{r['circle_diameter']:g}px/{r['circle_fov']:g}"
        rows.append((r['name'], f"{r['width']}x{r['height']}", deg(r['hfov']), deg(r['vfov']),
                     deg(r['dfov']), circle, r['given'], r['source']))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]) - 1)]
    for row in rows:
        print('  '.join(cell.ljust(w) for cell, w in zip(row, widths)) + '  ' + row[-1])
    return 0
