"""Progress bars of the long commands (`identify`, `analyze`, `bench`, `teach-bench`, the
identification benchmark): one small wrapper around tqdm that they all use.

A bar counts real units of work (experiments, analysis stages, controller cycles, strategies)
against a total known up front, so tqdm can give the time left. It is drawn on stderr, and
only when stderr is a terminal (tqdm's ``disable=None``): in a pipe, a CI log or a test the
command's output is exactly what it was without bars. ``--no-progress``
(:func:`add_progress_argument`) turns it off on a terminal too; ``enabled=True`` forces it (a
test drawing into a StringIO).

While a bar is drawn, the root logger's console handlers and the lines the command prints
(:meth:`ProgressBar.write`) go through tqdm, which clears the bar, writes the line and draws
the bar again, so the two never tear each other apart.

The bar belongs to the process that made it. A process forked while it is open (the analysis's
workers, :mod:`control.identification.parallel`) inherits an inert copy: updates there do
nothing and its end never draws a second bar. tqdm's monitor thread is not started (the bar
is updated by the work itself), so no thread outlives a bar.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import sys
import weakref
from collections.abc import Iterator
from typing import IO, Any

#: the option that turns every bar off
NO_PROGRESS_OPTION = "--no-progress"


def add_progress_argument(p: argparse.ArgumentParser) -> None:
    """``--no-progress`` on a command that draws a bar (:func:`progress_enabled` reads it)."""
    p.add_argument(
        NO_PROGRESS_OPTION,
        dest="no_progress",
        action="store_true",
        help="no progress bar (it is drawn on stderr only when stderr is a terminal)",
    )


def progress_enabled(args: argparse.Namespace) -> bool | None:
    """``enabled`` for :func:`progress_bar` from parsed arguments: False with
    ``--no-progress``, else None (drawn when stderr is a terminal)."""
    return False if getattr(args, "no_progress", False) else None


@functools.cache
def _tqdm_class() -> type:
    """tqdm without its monitor thread; imported on the first bar, not with the command."""
    from tqdm import tqdm

    class _Tqdm(tqdm):  # type: ignore[misc]
        monitor_interval = 0

    return _Tqdm


#: the bars open in this process, made inert in a forked child (:func:`_forget_in_child`)
_open_bars: weakref.WeakSet[ProgressBar] = weakref.WeakSet()


def _forget_in_child() -> None:
    for bar in list(_open_bars):
        bar._tqdm.disable = True  # tqdm's own close (and __del__) then draw nothing


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_child)


class ProgressBar:
    """One bar counting units of work; made by :func:`progress_bar`.

    ``n`` and ``total`` count whether the bar is drawn or not, so a caller (or a test) can
    always see how far the work got.
    """

    def __init__(self, tqdm_bar: Any, desc: str, total: int | None) -> None:
        self._tqdm = tqdm_bar
        self._desc = desc
        self._pid = os.getpid()
        self.n = 0
        self.total = total
        self.closed = False

    @property
    def shown(self) -> bool:
        """True while the bar is drawn (forced, or stderr is a terminal)."""
        return not self.closed and not self._tqdm.disable and self._ours()

    def _ours(self) -> bool:
        return os.getpid() == self._pid

    def advance(self, units: int = 1, label: str | None = None) -> None:
        """``units`` more done; ``label`` (optional) names what runs now."""
        self.update_to(self.n + units, label)

    def update_to(self, n: int, label: str | None = None) -> None:
        """``n`` units done in all (never counts back); ``label`` as in :meth:`advance`."""
        if self.closed or not self._ours():
            return
        if label is not None:
            self.set_label(label, refresh=False)
        if n > self.n:
            if self.shown:
                self._tqdm.update(n - self.n)
            self.n = n
        elif label is not None and self.shown:
            self._tqdm.refresh()

    def set_label(self, label: str, refresh: bool = True) -> None:
        """Name what runs now, after the bar's name."""
        if self.shown:
            text = f"{self._desc} {label}" if label else self._desc
            self._tqdm.set_description_str(text, refresh=refresh)

    def set_note(self, text: str) -> None:
        """A note after the counts (tqdm's postfix)."""
        if self.shown:
            self._tqdm.set_postfix_str(text)

    def write(self, line: str, file: IO[str] | None = None) -> None:
        """Print ``line`` (to stdout by default) above the bar; a plain ``print`` when no bar
        is drawn, so the output is the same as without bars."""
        out = file if file is not None else sys.stdout
        if self.shown:
            self._tqdm.write(line, file=out)
        else:
            print(line, file=out, flush=True)

    def close(self) -> None:
        """Draw the bar a last time and leave it on screen (once; not in a forked child)."""
        if self.closed or not self._ours():
            return
        self.closed = True
        _open_bars.discard(self)
        self._tqdm.close()


@contextlib.contextmanager
def progress_bar(
    total: int | None,
    desc: str,
    unit: str = "step",
    *,
    enabled: bool | None = None,
    file: IO[str] | None = None,
    bar_format: str | None = None,
) -> Iterator[ProgressBar]:
    """A bar of ``total`` ``unit``s named ``desc`` on ``file`` (default stderr), closed on exit.

    ``enabled``: None draws it only when ``file`` is a terminal, False never (``--no-progress``),
    True always. While it is drawn, console logging goes through tqdm (module docstring).
    ``bar_format``: tqdm's, for a bar that shows something else than its own time left.
    """
    out = file if file is not None else sys.stderr
    tqdm_bar = _tqdm_class()(
        total=total,
        desc=desc,
        unit=unit,
        file=out,
        disable=None if enabled is None else not enabled,
        dynamic_ncols=True,
        bar_format=bar_format,
    )
    bar = ProgressBar(tqdm_bar, desc, total)
    _open_bars.add(bar)
    try:
        if bar.shown:
            from tqdm.contrib.logging import logging_redirect_tqdm

            with logging_redirect_tqdm(tqdm_class=_tqdm_class()):
                yield bar
        else:
            yield bar
    finally:
        bar.close()
