"""Frame-sized blocks kept in the heap between frames (glibc malloc), so that a stream of frames
costs no page faults.

Why: a frame taken from DDS and a frame published allocate a frame-sized block each, and free
both once the frame is done. glibc serves a block of at least ``M_MMAP_THRESHOLD`` with its own
mmap and returns it to the kernel when freed; below that threshold a freed block stays in the
heap unless the free space at the top of the heap exceeds ``M_TRIM_THRESHOLD``, which is then
returned too. Either way every page of the next frame is faulted in again: at 1080p bgr8 two
6.2 MB blocks per frame are about 3,000 page faults a frame (test/core/streaming/test_heap.py). glibc adjusts
both thresholds itself (each mmapped block freed raises the mmap threshold to its size and the
trim threshold to twice that), so whether a process faults depends on which blocks it happened
to free before. In earlier runs the same node's latency at 1080p bgr8 30 fps swung between
processes (28.92 and 32.78 ms in the two rounds of one run); in benchmarks/results/
serialized_path.md the previous node, which leaves the thresholds alone, faulted 2,263 times a
frame in one of its two rounds and not at all in the other.

``keep_frames_in_heap`` sets the thresholds where glibc's own rule ends at most (mmap threshold
32 MiB, the ceiling of that rule on 64-bit hosts; trim threshold twice that), once, at start: blocks below
32 MiB (a 4K bgr8 frame is 24.9 MB) are reused from the heap frame after frame, and up to 64 MiB
of freed blocks are kept for the next frame instead of being returned to the kernel.
"""
import ctypes
import os
import platform
from typing import Optional

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20
"""glibc's DEFAULT_MMAP_THRESHOLD_MAX on 64-bit hosts, the highest its dynamic rule goes."""
TRIM_THRESHOLD_BYTES = 2 * MMAP_THRESHOLD_BYTES
"""What glibc's dynamic rule sets with that mmap threshold."""
_USER_SETTINGS = ('MALLOC_MMAP_THRESHOLD_', 'MALLOC_TRIM_THRESHOLD_')
_USER_TUNABLES = ('glibc.malloc.mmap_threshold', 'glibc.malloc.trim_threshold')


def _libc() -> Optional[ctypes.CDLL]:
    if platform.system() != 'Linux' or platform.libc_ver()[0] != 'glibc':
        return None
    try:
        libc = ctypes.CDLL(None)
        return libc if hasattr(libc, 'mallopt') else None
    except OSError:
        return None


def keep_frames_in_heap(environ=os.environ) -> str:
    """Set glibc's mmap and trim thresholds for a stream of frames (see the module); returns
    what was done, for the log. A user's own MALLOC_MMAP_THRESHOLD_ / MALLOC_TRIM_THRESHOLD_ (or
    the same glibc tunables) win: then nothing is changed. Other C libraries: nothing to do."""
    tunables = environ.get('GLIBC_TUNABLES', '')
    user = [name for name in _USER_SETTINGS if name in environ] + \
        [name for name in _USER_TUNABLES if name in tunables]
    if user:
        return f'allocator as the environment sets it ({", ".join(user)})'
    libc = _libc()
    if libc is None:
        return 'allocator unchanged (not glibc)'
    libc.mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    if not (libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) and
            libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)):
        return 'allocator unchanged (glibc refused the thresholds)'
    return (f'frames up to {MMAP_THRESHOLD_BYTES >> 20} MiB reused from the heap '
            f'(glibc mmap threshold {MMAP_THRESHOLD_BYTES >> 20} MiB, trim threshold {TRIM_THRESHOLD_BYTES >> 20} MiB)')


def return_free_memory() -> bool:
    """Give the pages of freed blocks back to the kernel (glibc ``malloc_trim(0)``: every arena,
    the middle of the heap too); False where there is nothing to call.

    Why: the thresholds ``keep_frames_in_heap`` sets keep every freed block under 32 MiB in the
    heap, which is what a stream of same-sized frames wants, but rectification maps and their
    build's temporaries are such blocks too: maps of other frame sizes, evicted or released, and
    a new calibration's temporaries stayed resident (odd-size bgr8 frames of 5 sizes, 2 rounds:
    +210 MiB of RSS after every odd size's maps were released, with 2.3 MB of maps in force).
    Called after maps are built or dropped (rare events); the next frame then faults its
    blocks in once."""
    libc = _libc()
    if libc is None or not hasattr(libc, 'malloc_trim'):
        return False
    libc.malloc_trim.argtypes = (ctypes.c_size_t,)
    libc.malloc_trim(0)
    return True


def resident_bytes() -> int:
    """The process's resident memory now (Linux /proc/self/statm), 0 where unknown."""
    try:
        with open('/proc/self/statm') as f:
            return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')
    except (OSError, ValueError, IndexError):
        return 0
