# PYTHON_ARGCOMPLETE_OK (tab completion when argcomplete is installed: see main)
"""``zeroshot-calib``: the ROS-free command line, a module per verb (as ros2cli has it).

    zeroshot-calib solve --width 1920 --height 1080 --hfov 118 --vfov 69 [--json] [--yaml FILE]
    zeroshot-calib solve --batch cameras.csv [--yaml-dir DIR]
    zeroshot-calib solve --preset gopro_hero9_wide [--hfov 120] [--json]
    zeroshot-calib presets [--json]
    zeroshot-calib rectify IN.png -o OUT.png --hfov 118 --vfov 69
    zeroshot-calib rectify IN.png -o OUT.png --calibration CALIB.yaml | --preset NAME
    zeroshot-calib calibrate 'images/*.png' [--board 8x6 --square 0.108] [--hfov H --vfov V] [--single IMG]
    zeroshot-calib evaluate 'images/*.png' --hfov H --vfov V [--json] [--save-corners FILE]

Errors exit with status 2 and one line on stderr, never a traceback; status 1: some --batch rows
failed (or an internal error, reported in one line); status 3: refine / calibrate ran but did not
adopt their result (the zero-shot camera of the spec is printed and written, and the file says so in
a comment). Warnings are one line each on stderr, ``zeroshot-calib: warning: ...``.
"""
import os

# OpenCV's own pixel limit, read when cv2 loads (the header check of core/file_input.py comes
# first; this covers formats whose header it does not parse). A user's setting wins.
os.environ.setdefault('OPENCV_IO_MAX_IMAGE_PIXELS', '50000000')
# One BLAS thread, read when numpy's OpenBLAS loads: the fits solve thousands of tiny systems, which
# a second thread never speeds up, and beside a second run on the cores OpenBLAS's waiting threads
# made `calibrate` 5x slower with Ubuntu 24.04's numpy (benchmarks/results/blas_threads.md). A
# user's setting wins.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

from .command import build_parser, main  # noqa: E402

__all__ = ['build_parser', 'main']
