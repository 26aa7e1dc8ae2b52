"""The spec-sheet solver (layer 1): resolution + fields of view -> camera, no image needed.

``spec`` (what a spec sheet gives, validated), ``presets`` (published spec sheets),
``solver`` (the paper's square-pixel equations 12-27, and the choice of projection) and
``wide_solver`` (the same for the wide-FOV model past 180 degrees), ``brent`` (the root finder,
scipy's Brent in pure Python). Imports ``core.lens``.
"""
