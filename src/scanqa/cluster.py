"""Running many independent tasks: serially, or on Dask distributed (docs/cluster.rst).

:func:`run_tasks` calls ``fn(shared, item)`` for every :class:`Task` and returns one small
row (a dict) per task, keyed by the task's key. The engines:

* **serial** - in this process, one task after another (``--serial``, or when Dask is
  not installed: then it says so once);
* **local cluster** - a Dask ``LocalCluster`` of worker processes on this machine,
  ``threads_per_worker=1`` (the numerical kernels use the cores themselves; one task per
  process keeps memory predictable);
* **existing cluster** - ``Client(scheduler_address)``.

``shared`` (the calibration, config, layout and settings of a batch) is shipped to the
workers once: ``client.scatter(shared, broadcast=True)`` puts one copy on every worker
and each task receives the worker's copy; a worker that joins later (a replacement for
a dead one) fetches it from a peer. Tasks read their inputs and write their outputs
themselves, on a file system every worker sees, and return only their row: no point
cloud travels through the scheduler.

A worker that dies mid-task is replaced by its nanny and its tasks run again elsewhere
(Dask's scheduler does this); a task that kills workers repeatedly (e.g. out of memory)
ends as a failed row. Rows are collected by key, so a task run twice still gives one
row. Tasks must therefore be idempotent: they publish their outputs atomically.
"""

from __future__ import annotations

import contextlib
import logging
import os
import resource
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

from scanqa.errors import InputError, ScanQAError
from scanqa.progress import Progress

log = logging.getLogger(__name__)

#: Install hint of the optional engine.
INSTALL_HINT = "pip install 'scanqa[cluster]'"
#: Seconds to wait for an existing scheduler before giving up.
CONNECT_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class EngineOptions:
    """How to run the tasks.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); None starts a
        LocalCluster.
    workers : int, optional
        Worker processes of the LocalCluster [-]; default the number of cores.
    serial : bool
        Run in this process, without Dask.
    dashboard : str
        Address of the LocalCluster's dashboard (``":8787"``; ``":0"`` any free port).
    """

    scheduler: str | None = None
    workers: int | None = None
    serial: bool = False
    dashboard: str = ":8787"


@dataclass(frozen=True)
class Task:
    """One task: ``key`` identifies it (one row per key), ``item`` is its small input."""

    key: str
    item: object


@dataclass
class EngineReport:
    """What ran: the engine's description, its dashboard and each worker's peak memory."""

    engine: str
    dashboard: str | None = None
    worker_peak_mb: dict = field(default_factory=dict)  # worker -> peak RSS [MB]
    seconds: float = 0.0


def dask_available() -> bool:
    """Whether ``dask.distributed`` can be imported."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        return False
    return True


def failed_row(key: str, err: BaseException | str) -> dict:
    """The row of a task that raised: its key, status "failed" and the message."""
    if isinstance(err, ScanQAError):
        message = str(err)
    elif isinstance(err, BaseException):
        message = f"{type(err).__name__}: {err}"
    else:
        message = str(err)
    return {"scan": key, "status": "failed", "error": message}


def guarded(fn: Callable[[object, object], dict], shared: object, key: str,
            item: object) -> dict:
    """``fn(shared, item)``, or a failed row when it raises (the others go on)."""
    try:
        return fn(shared, item)
    except Exception as err:  # one task's failure, whatever it is, is recorded
        log.debug(f"task {key} failed", exc_info=True)
        return failed_row(key, err)


def peak_rss_mb() -> float:
    """Peak resident memory of this process [MB]."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class _Tally:
    """Progress of the tasks: done, failed and the ETA (:mod:`scanqa.progress`)."""

    def __init__(self, desc: str, total: int, unit: str) -> None:
        self.bar = Progress(desc, total, unit, log)
        self.total, self.done, self.failed = total, 0, 0
        self.t0 = time.perf_counter()

    def __call__(self, key: str, row: dict) -> None:
        self.done += 1
        self.failed += row.get("status") == "failed"
        rate = (time.perf_counter() - self.t0) / self.done
        eta = rate * (self.total - self.done)
        self.bar.update(1, note=f"{key} {row.get('status', 'ok')}, {self.failed} failed, "
                                f"ETA {_duration(eta)}")


def _duration(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else \
        f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"


def run_tasks(fn: Callable[[object, object], dict], shared: object, tasks: Sequence[Task],
              options: EngineOptions, desc: str, unit: str = "scan"
              ) -> tuple[dict[str, dict], EngineReport]:
    """Run ``fn(shared, task.item)`` for every task; rows keyed by task key.

    Parameters
    ----------
    fn : callable
        A module-level function (workers import it by name) returning a small dict.
    shared : object
        What every task needs (picklable); shipped to each worker once.
    tasks : sequence of Task
        Distinct keys.
    options : EngineOptions
        Which engine.
    desc, unit : str
        For the progress lines ("batch", "scan").

    Returns
    -------
    (dict, EngineReport)
        One row per task key (a failed row when the task raised or its workers died)
        and what ran.

    Raises
    ------
    InputError
        When ``options.scheduler`` is given and Dask is not installed or the scheduler
        cannot be reached.
    """
    if not tasks:  # a resumed run with nothing left: no cluster to start
        return {}, EngineReport("nothing left to run")
    if not options.serial and not dask_available():
        if options.scheduler:
            raise InputError(f"a scheduler address needs Dask distributed ({INSTALL_HINT})")
        log.info(f"{desc}: Dask is not installed ({INSTALL_HINT}): running serially, "
                 "with the same outputs")
        options = EngineOptions(serial=True)
    t0 = time.perf_counter()
    tally = _Tally(desc, len(tasks), unit)
    with tally.bar:
        if options.serial:
            rows, report = _run_serial(fn, shared, tasks, tally), EngineReport("serial")
            report.worker_peak_mb = {"this process": peak_rss_mb()}
        else:
            rows, report = _run_dask(fn, shared, tasks, options, desc, tally)
    report.seconds = time.perf_counter() - t0
    return rows, report


def _run_serial(fn, shared, tasks, tally) -> dict[str, dict]:
    rows = {}
    for task in tasks:
        rows[task.key] = guarded(fn, shared, task.key, task.item)
        tally(task.key, rows[task.key])
    return rows


@contextlib.contextmanager
def open_client(options: EngineOptions) -> Iterator[tuple[object, EngineReport]]:
    """A Dask client on a new LocalCluster or an existing scheduler (closed on exit).

    Raises
    ------
    InputError
        When the scheduler cannot be reached.
    """
    from distributed import Client, LocalCluster

    if options.scheduler:
        try:
            client = Client(options.scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as err:
            raise InputError(f"cannot reach the Dask scheduler at {options.scheduler}: "
                             f"{err} (start one with 'dask scheduler' and workers with "
                             "'dask worker ADDRESS', or give no scheduler address to use "
                             "this machine)") from None
        with client:
            n = len(client.scheduler_info().get("workers", {}))
            yield client, EngineReport(f"scheduler {options.scheduler} ({n} workers)",
                                       _dashboard(client))
        return
    import dask

    n = options.workers or os.cpu_count() or 1
    # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_ set, which turns off glibc's
    # adaptive mmap threshold: every large temporary array is then mapped and unmapped
    # afresh, and the simulator renders 3x slower (measured: 8 scans 27 s serial, 79 s
    # with that variable). The workers keep the allocator's default.
    environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ",
                                                {}).items() if k != "MALLOC_TRIM_THRESHOLD_"}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}), \
            LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                         dashboard_address=options.dashboard,
                         silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client, EngineReport(f"local cluster ({n} worker processes)",
                                   _dashboard(client))


def _dashboard(client) -> str | None:
    try:
        import bokeh  # noqa: F401  (the dashboard needs it)
    except ImportError:
        return None
    return client.dashboard_link


def _run_dask(fn, shared, tasks, options, desc, tally) -> tuple[dict[str, dict], EngineReport]:
    from distributed import as_completed

    with open_client(options) as (client, report):
        log.info(f"{desc}: {report.engine}; dashboard "
                 + (report.dashboard or "unavailable (pip install bokeh)"))
        shared_future = client.scatter(shared, broadcast=True, hash=False)
        run = uuid.uuid4().hex[:8]  # keys unique on a long-lived scheduler
        futures = {client.submit(guarded, fn, shared_future, t.key, t.item,
                                 key=f"{desc}-{run}-{t.key}", pure=False): t.key
                   for t in tasks}
        rows = {}
        for future in as_completed(futures):
            key = futures[future]
            try:
                rows[key] = future.result()
            except Exception as err:  # KilledWorker, lost data: the task's row says so
                rows[key] = failed_row(key, f"its worker died repeatedly ({type(err).__name__}"
                                            f": {err}); out of memory?")
            tally(key, rows[key])
            future.release()
        with contextlib.suppress(Exception):
            report.worker_peak_mb = client.run(peak_rss_mb)
    return rows, report
