"""Progress of long calls.

Every long Client method (curvature, project, high_order_nodes, integrate, refine, membrane,
membrane_pressure, flow, membrane_solve) takes `progress=`: a callable(phase, done, total) called as the server
reports (done of total units of the phase; total 0: unknown; per phase, done never
decreases), or True for a tqdm bar per phase on stderr (one text line per report when
tqdm is not installed). watch_job / wait_job take a callable(event) (tqdm_callback(),
text_callback()) or True.
"""
import contextlib
import sys
from typing import Any, Callable, Iterator, Optional, TextIO, Union

ProgressFn = Callable[[str, int, int], None]
ProgressArg = Union[None, bool, ProgressFn]


class PhaseBars:
    """A callable(phase, done, total) drawing a tqdm bar per phase on `stream` (stderr),
    or writing `phase done/total` lines there when tqdm is not installed. close() ends
    the last bar."""

    def __init__(self, stream: Optional[TextIO] = None, **tqdm_kwargs: Any):
        try:
            from tqdm import tqdm
        except ImportError:
            tqdm = None
        self._tqdm, self._stream, self._kwargs = tqdm, stream, tqdm_kwargs
        self._bar, self._phase = None, None

    def __call__(self, phase: str, done: int, total: int) -> None:
        if self._tqdm is None:
            out = self._stream or sys.stderr
            out.write("geomfit: %s %d%s\n" % (phase, done, "/%d" % total if total else ""))
            return
        if phase != self._phase:
            self.close()
            self._phase = phase
            self._bar = self._tqdm(total=total or None, desc=phase, file=self._stream or sys.stderr, **self._kwargs)
        if total and self._bar.total != total:
            self._bar.total = total
        self._bar.update(max(0, done - self._bar.n))

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        self._bar, self._phase = None, None


class _Monotone:
    """Passes on a report only when its done is above the phase's last one (a retried
    call starts over; threads of the server finish out of order)."""

    def __init__(self, fn: ProgressFn):
        self._fn, self._phase, self._done = fn, None, -1

    def __call__(self, phase: str, done: int, total: int) -> None:
        if phase == self._phase and done <= self._done:
            return
        self._phase, self._done = phase, done
        self._fn(phase, done, total)


@contextlib.contextmanager
def reporting(progress: ProgressArg) -> Iterator[Optional[ProgressFn]]:
    """The reporter a long method calls for its `progress=` argument: None for None or
    False, PhaseBars() (closed at the end) for True, the callable itself otherwise;
    monotone per phase."""
    if progress is None or progress is False:
        yield None
        return
    if progress is True:
        bars = PhaseBars()
        try:
            yield _Monotone(bars)
        finally:
            bars.close()
        return
    if not callable(progress):
        raise TypeError("progress must be None, True or a callable(phase, done, total), got %r" % (progress,))
    yield _Monotone(progress)


def tqdm_callback(**tqdm_kwargs: Any) -> Callable[[Any], None]:
    """A watch_job progress callback drawing a tqdm bar per job phase (done of total),
    or a one-line text report per event on stderr when tqdm is not installed."""
    try:
        from tqdm import tqdm
    except ImportError:
        return text_callback()
    state = {"bar": None, "key": None}

    def update(event: Any) -> None:
        key = (event.step, event.phase)
        if key != state["key"]:
            if state["bar"] is not None:
                state["bar"].close()
            state["key"] = key
            state["bar"] = tqdm(total=event.total or None, desc="%s %d" % (event.phase, event.step), **tqdm_kwargs)
        bar = state["bar"]
        bar.update(max(0, event.done - bar.n))
        if event.final:
            bar.close()
    return update


def text_callback(stream: Optional[TextIO] = None) -> Callable[[Any], None]:
    """A watch_job progress callback writing `seq phase step done/total` lines."""
    def update(event: Any) -> None:
        out = stream or sys.stderr
        total = "/%d" % event.total if event.total else ""
        out.write("job %s: %d %s step %d %d%s\n" % (event.job_id, event.seq, event.phase, event.step, event.done, total))
    return update
