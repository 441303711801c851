"""Run the analysis with single-threaded BLAS.

The analysis does many small dense solves (~100 columns) and dot products over ~10⁴-10⁵
samples. OpenBLAS threads them, and on a busy machine a thread waiting for a core turns a 3 ms
eigen-solve into 70 ms (measured on the cell PC class of machine: the whole analysis was 20×
slower). One thread is as fast for these sizes and immune to load. numpy and scipy each bundle
their own OpenBLAS; both are found among the loaded libraries (Linux ``/proc/self/maps``) and
set through their ``*_set_num_threads`` entry points, and restored afterwards. Where that is not
possible (another platform, another BLAS) this does nothing.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager

_PREFIXES = ("openblas", "scipy_openblas")
_SUFFIXES = ("", "64_")


def _openblas_handles() -> list[tuple[object, object]]:
    paths: set[str] = set()
    try:
        with open(f"/proc/{os.getpid()}/maps") as fh:
            for line in fh:
                path = line.rsplit(None, 1)[-1]
                if "openblas" in os.path.basename(path):
                    paths.add(path)
    except OSError:
        return []
    out = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in _PREFIXES:
            for suffix in _SUFFIXES:
                get = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
                put = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
                if get is not None and put is not None:
                    out.append((get, put))
    return out


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context in which numpy's and scipy's OpenBLAS use one thread."""
    handles = _openblas_handles()
    before = []
    for get, put in handles:
        try:
            before.append(int(get()))  # type: ignore[operator]
            put(1)  # type: ignore[operator]
        except (OSError, ValueError):
            before.append(-1)
    try:
        yield
    finally:
        for (_, put), n in zip(handles, before, strict=True):
            if n > 0:
                put(n)  # type: ignore[operator]
