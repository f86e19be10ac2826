"""Progress of long work: a line per phase with its time, and a bar over long loops.

Two helpers, for the library and for the packages above it (the FMU builds, the closed
loop, the batch runs)::

    from solver.progress import bar, phase

    with phase("building RRRDirectKinematics.fmu", detail="about 20 s") as ph:
        for item in bar(items, desc="maps", unit="map"):
            ...
        ph.summary = "3 maps, 12.1 MB"
    # stderr: "building RRRDirectKinematics.fmu ... (about 20 s)"
    #         "building RRRDirectKinematics.fmu: done in 17.3 s (3 maps, 12.1 MB)"

* :func:`phase` writes a line when a phase starts and one with its wall time when it ends
  (or fails); the time is also on the object it yields (``ph.seconds``).  With ``after=2``
  it speaks only if the phase is still running after 2 s (work that is slow only sometimes:
  kernels compile on the first run, then load from numba's disk cache).  A phase that runs on
  with nothing else written says so every :data:`HEARTBEAT` seconds ("compiling ...: 24 s so
  far"; the innermost open phase only, never over a progress bar): a log or a terminal never
  stays silent long enough to look hung.
* :func:`bar` is a tqdm progress bar.  It appears only once its loop has run for
  :data:`BAR_DELAY` seconds (short loops print nothing).  On a terminal it redraws in place;
  when stderr is not a terminal (a log file, CI, ``pytest -s``) it writes a plain line at
  most every :data:`LOG_INTERVAL` seconds, so a log shows progress without control characters.
* :func:`note` writes one line (e.g. where a cache writes).

Everything goes to ``sys.stderr`` as it is at the call (pytest's capture sees it).  tqdm is
imported when the first bar is made, not with :mod:`solver`: an FMU, which bundles ``solver``
and never builds a map, does not need it on its host (without tqdm a bar counts silently).
Silence it with ``RRR_DK_PROGRESS=0`` in the environment, :func:`set_enabled` or the
:func:`silenced` context manager; an ``enabled=`` argument of True or False overrides them
for one call, None follows them.
"""
from __future__ import annotations

import contextlib
import importlib
import os
import sys
import threading
import time
from collections.abc import Iterable, Iterator

__all__ = ["PROGRESS_ENV", "BAR_DELAY", "LOG_INTERVAL", "HEARTBEAT", "Phase", "phase", "bar", "note", "is_on", "set_enabled",
           "silenced"]

#: Environment variable: ``0``, ``off``, ``false`` or ``no`` silence progress output by default.
PROGRESS_ENV = "RRR_DK_PROGRESS"
#: A bar appears once its loop has run this long, s.
BAR_DELAY = 2.0
#: Seconds between two progress lines when stderr is not a terminal.
LOG_INTERVAL = 5.0
#: A phase that runs on writes a line after this many seconds without one (:func:`phase`).
HEARTBEAT = 8.0

_last_line = [time.perf_counter()]    # when this module last wrote a line (note, a bar's line in a log)
_open: list = []                      # the phases running, innermost last (only that one says it goes on)

_default: bool | None = None          # None: from the environment


def is_on(override: bool | None = None) -> bool:
    """Whether progress output is on: ``override`` if it is True or False, else the default
    (:func:`set_enabled`, else on unless ``$RRR_DK_PROGRESS`` is ``0``/``off``/``false``/``no``)."""
    if override is not None:
        return bool(override)
    if _default is not None:
        return _default
    return os.environ.get(PROGRESS_ENV, "1").strip().lower() not in ("0", "off", "false", "no")


def set_enabled(on: bool | None) -> None:
    """Turn progress output on or off for the process; None: back to the environment's choice."""
    global _default
    _default = None if on is None else bool(on)


@contextlib.contextmanager
def silenced() -> Iterator[None]:
    """No progress output inside the block (restores the previous default after it)."""
    global _default
    saved = _default
    _default = False
    try:
        yield
    finally:
        _default = saved


def note(text: str, enabled: bool | None = None) -> None:
    """Write ``text`` as one line to stderr, if progress output is on (``enabled``: as in :func:`phase`)."""
    if is_on(enabled):
        sys.stderr.write(text + "\n")
        sys.stderr.flush()
        _last_line[0] = time.perf_counter()


def _bar_drawing() -> bool:
    """Whether a tqdm bar is on screen (a heartbeat line would break it)."""
    tqdm = sys.modules.get("tqdm")
    live = getattr(getattr(tqdm, "tqdm", None), "_instances", ()) if tqdm else ()
    return any(not getattr(b, "disable", True) for b in list(live))


def _heartbeat(ph: "Phase", t0: float, stop: threading.Event) -> None:
    """Say that ``ph`` goes on whenever nothing was written for :data:`HEARTBEAT` seconds (a thread)."""
    while not stop.wait(min(1.0, HEARTBEAT / 4)):
        now = time.perf_counter()
        speaking = [p for p in list(_open) if p._said]
        if now - _last_line[0] >= HEARTBEAT and speaking and speaking[-1] is ph and not _bar_drawing():
            note(f"{ph.name}: {now - t0:.0f} s so far", True)


class Phase:
    """One timed phase (:func:`phase`).

    Attributes
    ----------
    name : str
    seconds : float or None
        Wall time of the phase, s (None until it ends).
    summary : str
        Set inside the block: appended to the end line in parentheses.
    """

    def __init__(self, name: str):
        self.name = name
        self.seconds: float | None = None
        self.summary = ""
        self._said = False              # its start line is written (it may say it goes on)


@contextlib.contextmanager
def phase(name: str, detail: str = "", enabled: bool | None = None, after: float = 0.0,
          heartbeat: bool = True) -> Iterator[Phase]:
    """Time a phase of long work and say so on stderr.

    Parameters
    ----------
    name : str
        What is being done ("building map tensor posture 1 at 10 mm, 2 deg").
    detail : str
        Appended to the start line in parentheses (an expected duration, a path).
    enabled : bool, optional
        True/False: write or not, whatever the default; None: the default (:func:`is_on`).
    after : float
        Say nothing unless the phase is still running after this many seconds (then the start
        line, and the end line when it ends): for work that is slow only sometimes, such as
        kernels that compile on the first run and load from numba's cache after.
    heartbeat : bool
        Say every :data:`HEARTBEAT` s of silence that the phase goes on (False: the work runs in a
        child process that reports its own phases on the same stderr).

    Yields
    ------
    Phase
        Its ``seconds`` is set when the block ends, also when it raises.
    """
    ph = Phase(name)
    lock, done = threading.Lock(), [False]
    stop = threading.Event()

    def start():
        with lock:
            if not done[0]:
                note(f"{name} ..." + (f" ({detail})" if detail else ""), True)
                ph._said = True
                if heartbeat:
                    threading.Thread(target=_heartbeat, args=(ph, t0, stop), daemon=True,
                                     name=f"progress heartbeat: {name}").start()
    t0 = time.perf_counter()
    _open.append(ph)
    timer = None
    if is_on(enabled):
        if after > 0:
            timer = threading.Timer(after, start)
            timer.daemon = True
            timer.start()
        else:
            start()
    outcome = "done in {:.1f} s"
    try:
        yield ph
    except BaseException as exc:
        outcome = f"failed after {{:.1f}} s ({type(exc).__name__})"
        raise
    finally:
        ph.seconds = time.perf_counter() - t0
        if timer is not None:
            timer.cancel()
        stop.set()
        with lock:
            done[0] = True
        if ph in _open:
            _open.remove(ph)
        if ph._said:
            summary = f" ({ph.summary})" if ph.summary and outcome.startswith("done") else ""
            note(f"{name}: {outcome.format(ph.seconds)}{summary}", True)


class _Lines:
    """A file for tqdm that writes each refresh as its own line (for logs: no carriage returns)."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str) -> None:
        text = text.replace("\r", "").strip()
        if text:
            self.stream.write(text + "\n")
            _last_line[0] = time.perf_counter()

    def flush(self) -> None:
        self.stream.flush()


class _Silent:
    """What :func:`bar` gives without tqdm: it passes the items through and counts, silently."""

    def __init__(self, iterable=None, total=None, **_):
        self.iterable, self.total, self.n = iterable, total, 0

    def __iter__(self):
        for item in self.iterable:
            self.n += 1
            yield item

    def update(self, n: int = 1) -> None:
        self.n += n

    def set_postfix(self, *args, **kwargs) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def bar(iterable: Iterable | None = None, total: int | None = None, desc: str = "", unit: str = "it",
        enabled: bool | None = None, **kwargs):
    """A tqdm progress bar on stderr, quiet for short loops and readable in logs.

    Parameters
    ----------
    iterable : iterable, optional
        What to loop over (else call ``update(n)`` on the bar and ``close()`` it, or use it in
        a ``with`` block).
    total : int, optional
        Number of steps (default ``len(iterable)`` when it has one).
    desc, unit : str
        Label in front of the bar, and the name of a step.
    enabled : bool, optional
        True/False: show or not, whatever the default; None: the default (:func:`is_on`).
    **kwargs
        More tqdm options (``unit_scale``, ``delay``, ``mininterval``, ...).

    Returns
    -------
    tqdm.tqdm
        Disabled (prints nothing, still counts) when progress output is off; a silent counter
        with the same ``update``/``close``/iteration if tqdm is not installed.
    """
    try:
        tqdm = importlib.import_module("tqdm").tqdm          # at the call: see the module docstring
    except ModuleNotFoundError:
        return _Silent(iterable, total)
    stream = sys.stderr
    tty = bool(getattr(stream, "isatty", lambda: False)())
    # in a log: a line at most every LOG_INTERVAL s, checked at every update (miniters=1), so tqdm's
    # monitor thread (which forces a refresh after maxinterval) has nothing to add
    options = {"delay": BAR_DELAY, "mininterval": 0.1 if tty else LOG_INTERVAL, "dynamic_ncols": tty,
               "ascii": not tty, **({} if tty else {"miniters": 1, "maxinterval": 6 * LOG_INTERVAL})}
    options.update(kwargs)
    return tqdm(iterable, total=total, desc=desc, unit=unit, file=stream if tty else _Lines(stream),
                disable=not is_on(enabled), **options)
