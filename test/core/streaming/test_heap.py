"""Frame-sized blocks stay in the heap (zeroshot_calib_ros/core/streaming/heap.py): a stream that
allocates and frees frames costs no page faults once the allocator is set, whatever the process
freed before. Each case runs in a fresh interpreter: glibc's thresholds are process-wide and
move with what a process has freed."""
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]

pytestmark = pytest.mark.skipif(platform.system() != 'Linux' or platform.libc_ver()[0] != 'glibc',
                                reason='glibc malloc thresholds: Linux with glibc only')

# What the node's frame path does per frame: the frame taken from DDS and the frame published,
# each a frame-sized block written in full, both freed once the frame is done.
STREAM = '''
import json, resource, sys
said = 'not called'
if sys.argv[1] == 'set':  # imported only then: importing frees blocks, which moves glibc's thresholds
    from zeroshot_calib_ros.core.streaming.heap import keep_frames_in_heap
    said = keep_frames_in_heap()
frame = bytearray(b'\\x01') * int(sys.argv[2])
faults = []
for _ in range(12):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    taken = bytes(frame)
    published = bytes(frame)
    del taken, published
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(json.dumps({'said': said, 'faults': faults}))
'''


def stream_faults(mode, frame_bytes, **env):
    environ = {k: v for k, v in os.environ.items() if not k.startswith('MALLOC_') and k != 'GLIBC_TUNABLES'}
    environ.update(PYTHONPATH=str(REPO), **env)
    out = subprocess.run([sys.executable, '-c', STREAM, mode, str(frame_bytes)], env=environ,
                         capture_output=True, text=True, timeout=60, check=True).stdout
    result = json.loads(out)
    return result['said'], result['faults'][2:]  # after the first frames: the steady state


BGR8_1080P = 1920 * 1080 * 3 + 64
PAGES = BGR8_1080P // 4096


def test_without_the_setting_every_frame_faults_its_pages_in_again():
    """The problem, on this glibc: two frames allocated and freed per frame are trimmed off the
    heap every time (the trim threshold glibc derives is twice one frame), so each frame's pages
    fault in anew, about 3,000 at 1080p bgr8."""
    _, faults = stream_faults('unset', BGR8_1080P)
    assert min(faults) >= 1.5 * PAGES, faults


def test_with_the_setting_a_stream_of_frames_faults_no_pages():
    said, faults = stream_faults('set', BGR8_1080P)
    assert said.startswith('frames up to 32 MiB reused from the heap'), said
    assert max(faults) <= 20, faults


def test_a_4k_bgr8_frame_is_below_the_threshold_too():
    _, faults = stream_faults('set', 3840 * 2160 * 3 + 64)
    assert max(faults) <= 20, faults


@pytest.mark.parametrize('env', [{'MALLOC_MMAP_THRESHOLD_': '131072'},
                                 {'GLIBC_TUNABLES': 'glibc.malloc.trim_threshold=131072'}])
def test_the_users_allocator_settings_win(env):
    """A user who tuned glibc (MALLOC_*_ or GLIBC_TUNABLES) keeps that tuning, and is told so."""
    said, faults = stream_faults('set', BGR8_1080P, **env)
    assert said.startswith('allocator as the environment sets it'), said
    assert next(iter(env)) in said or 'glibc.malloc.trim_threshold' in said
    assert min(faults) >= 1.5 * PAGES, faults  # their thresholds, not ours: the faults stay
