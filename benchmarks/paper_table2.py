#!/usr/bin/env python3
"""Table 2 of the paper next to our zero-shot solution, as a markdown table (one FOV read as the
paper reads it, ``lens_prior=False``).

    .venv/bin/python benchmarks/paper_table2.py
"""
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / 'test')]

from paper_table2 import load_table2  # noqa: E402
from zeroshot_calib_ros.core import CameraSpec, solve_zero_shot  # noqa: E402
from zeroshot_calib_ros.core.lens.fitting import fit_kannala_brandt  # noqa: E402


def fit_error_text(px: float) -> str:
    """Four decimals of a pixel, what matters to a user; below that the figure is rounding in the
    fit and its low digits vary with the CPU and BLAS."""
    return '< 0.0001' if px < 1e-4 else f'{px:.4f}'


def main():
    print('| camera | W x H | hfov | vfov | paper w* | ours w* | paper f* | ours f* | '
          'ours vs f_gt | KB4 fit max err (px) |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    for row in load_table2():
        spec = CameraSpec(int(row['width']), int(row['height']), row['hfov'], row['vfov'])
        # the paper's reading of one FOV (its C905 row: a pinhole), not the lens-law prior's
        solution = solve_zero_shot(spec, lens_prior=False)
        fit = fit_kannala_brandt(solution.camera)
        err = abs(solution.f - row['f_gt']) / row['f_gt'] * 100
        vfov = '-' if row['vfov'] is None else f"{row['vfov']:g}"
        print(f"| {row['camera']} | {spec.width} x {spec.height} | {row['hfov']:g} | {vfov} | "
              f"{row['omega']:.6f} | {solution.omega:.6f} | {row['f_star']:.1f} | {solution.f:.2f} | "
              f"{err:.1f}% | {fit_error_text(fit.max_error_px)} |")


if __name__ == '__main__':
    main()
