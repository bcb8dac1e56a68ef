"""Progress callbacks for Client.watch_job / Client.wait_job."""
import sys
from typing import Any, Callable, Optional, TextIO


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
