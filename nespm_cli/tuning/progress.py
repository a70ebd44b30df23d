"""Progress of ``nespm tune``: a line per 10 completed trials of each filter, from the process that
runs them or, with ``--jobs`` workers, from a thread that reads the shared studies."""
from __future__ import annotations

from typing import Callable


def progress_line(name: str, done: int, trials: int, best: float) -> str | None:
    """The progress line of filter ``name`` after ``done`` of ``trials`` trials (every 10th and the last)."""
    if done % 10 == 0 or done == trials:
        return f"{name}: {done}/{trials} trials, best score {best:.6g}"
    return None


def echo_progress(trials: int):
    """A ``report`` callable of :func:`tune_filter` (and :func:`watch_studies`) printing :func:`progress_line`
    to stderr."""
    import sys

    def report(name: str, done: int, best: float) -> None:
        line = progress_line(name, done, trials, best)
        if line:
            print(line, file=sys.stderr, flush=True)
    return report


def watch_studies(store, filters: tuple, trials: int, report: Callable[[str, int, float], None],
                  every: float = 2.0) -> Callable[[], None]:
    """Report the shared studies' progress while ``--jobs`` workers run them (a thread reading the
    Optuna storage ``store`` every ``every`` s: ``report(filter, completed, best)`` at each new count); returns
    the function that stops it (after a last reading)."""
    import threading

    from optuna.trial import TrialState

    stop = threading.Event()
    seen = {f: 0 for f in filters}

    def read() -> None:
        import optuna

        for f in filters:
            done = optuna.load_study(study_name=f, storage=store).get_trials(deepcopy=False,
                                                                              states=(TrialState.COMPLETE,))
            for n in range(seen[f] + 1, min(len(done), trials) + 1):
                report(f, n, min(tr.value for tr in done[:n]))
            seen[f] = max(seen[f], min(len(done), trials))

    def loop() -> None:
        while not stop.wait(every):
            try:
                read()
            except Exception:  # noqa: BLE001 - a busy database: read again at the next tick
                pass

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()

    def finish() -> None:
        stop.set()
        thread.join()
        try:
            read()
        except Exception:  # noqa: BLE001
            pass
    return finish


__all__ = ["echo_progress", "progress_line", "watch_studies"]
