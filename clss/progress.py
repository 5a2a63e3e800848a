"""Progress of long runs: a tqdm bar on a terminal; elsewhere (a pipe, a CI log, a
file) one plain line every few seconds, so that a logged run shows it is alive
without filling the log with bar redraws."""
from __future__ import annotations

import sys
import time

LOG_INTERVAL_S = 5.0


def progress(iterable, desc: str = "", unit: str = "it", total=None, file=None,
             interval: float = LOG_INTERVAL_S, status=None):
    """`status`: optional callable -> short text shown after the count (tqdm's postfix;
    appended to each plain line), read after every item."""
    out = file or sys.stderr
    if getattr(out, "isatty", lambda: False)():
        from tqdm import tqdm
        bar = tqdm(iterable, desc=desc, unit=unit, total=total, file=out, dynamic_ncols=True)
        return bar if status is None else _with_postfix(bar, status)
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)
    return _log_lines(iterable, desc, unit, total, out, interval, status)


def _with_postfix(bar, status):
    with bar:
        for item in bar:
            yield item
            bar.set_postfix_str(status(), refresh=False)


def _log_lines(iterable, desc, unit, total, out, interval, status=None):
    """Yield from iterable; every `interval` seconds print 'desc: n/total unit (rate,
    ETA)'. Nothing for runs shorter than one interval."""
    t0 = last = time.perf_counter()
    n = 0
    for item in iterable:
        yield item
        n += 1
        now = time.perf_counter()
        if now - last >= interval:
            last = now
            rate = n / (now - t0)
            line = f"{desc}: {n}" + (f"/{total}" if total else "") + f" {unit}s ({rate:.2f} {unit}/s"
            if total and rate > 0:
                line += f", ETA {(total - n) / rate:.0f} s"
            print(line + ")" + (f" {status()}" if status is not None else ""), file=out,
                  flush=True)


class Waiting:
    """A status line on stderr while something slow and silent runs (the first frame's
    kernel builds): `status()` every `interval` seconds, redrawn in place on a terminal,
    one plain line every LOG_INTERVAL_S elsewhere; nothing while it ends within one
    interval. `done(text)` stops it and prints `text` (when given) on a line of its own."""

    def __init__(self, status, file=None, interval: float | None = None):
        import threading
        self.status, self.out = status, file or sys.stderr
        self.tty = getattr(self.out, "isatty", lambda: False)()
        self.interval = interval or (1.0 if self.tty else LOG_INTERVAL_S)
        self._stop = threading.Event()
        self._drawn = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.wait(self.interval):
            line = self.status()
            print(("\r\033[K" + line) if self.tty else line, end="" if self.tty else "\n",
                  file=self.out, flush=True)
            self._drawn = True

    def done(self, text: str | None = None) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join()
        if self._drawn and self.tty:
            print("\r\033[K", end="", file=self.out, flush=True)
        if text:
            print(text, file=self.out, flush=True)
