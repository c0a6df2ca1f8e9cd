"""glibc's allocator set for the processes that run for days beside the bus (the page's, each recorder).

Why: by default glibc raises its mmap threshold to the largest block freed so far, after which large temporaries
come from the heap, and the heap keeps the pages of whatever it has freed. A process's resident memory then follows
the high-water mark of what it once held at once, and rises each time long-lived blocks keep a freed region from
being reused. In issue 29's soak the bytes the page's process held stayed flat (30.7-31.0 MB from minute 4 to 17)
while its heap grew 34.0 -> 35.9 MB and its RSS +0.23 MB/min; with the allocator set as here it gained
+0.08 MB/min over 30 minutes. A recorder, flat otherwise, stepped up 0.8 MB once, 4 minutes in, and stayed there,
which a 7-minute slope cannot tell from growth.

Two settings: every allocation of ``MMAP_FROM`` or more is mapped on its own and unmapped when freed (a fixed
``M_MMAP_THRESHOLD``), and every ``period`` s the whole pages of what was freed inside the heaps go back to the
system (``malloc_trim(0)``, ~1 ms, in a thread of its own). Without glibc nothing is done.
"""

from __future__ import annotations

import ctypes
import threading

M_MMAP_THRESHOLD = -3  # mallopt's parameter (glibc's malloc.h)
MMAP_FROM = 128 << 10  # glibc's default threshold, kept fixed
TRIM_S = 10.0


def keep_the_heap_to_what_is_held(stop: threading.Event, period: float = TRIM_S) -> None:
    """Fix the mmap threshold, then hand freed pages back every ``period`` s until ``stop`` is set."""
    try:
        libc = ctypes.CDLL(None)
        mallopt, trim = libc.mallopt, libc.malloc_trim
    except (OSError, AttributeError):
        return
    mallopt(M_MMAP_THRESHOLD, MMAP_FROM)
    trim.argtypes = [ctypes.c_size_t]
    while not stop.wait(period):
        trim(0)


def start(stop: threading.Event, period: float = TRIM_S) -> threading.Thread:
    """:func:`keep_the_heap_to_what_is_held` in a daemon thread of its own."""
    t = threading.Thread(target=keep_the_heap_to_what_is_held, args=(stop, period), name="heap", daemon=True)
    t.start()
    return t
