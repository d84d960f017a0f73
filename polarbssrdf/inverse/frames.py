"""Run independent frames serially, on a local Dask cluster, or on a remote one (one code path).

``run_frames(task, frames)`` calls ``task(frame)`` for every frame and
returns ``(records, failures)``: ``frame -> task's return value`` for the
frames that finished, ``frame -> reason`` for those that raised. With
``workers`` it starts a ``dask.distributed.LocalCluster`` of that many worker
processes with one thread each (the task sets Dr.Jit's own thread count to
match, so workers do not oversubscribe the cores); with ``scheduler`` it
submits to an existing cluster (``dask scheduler`` + ``dask worker`` on
machines that see the same paths); with neither, frames run in this process
one after another. A worker that dies mid-frame has its frame rescheduled by
Dask on another worker (up to ``allowed-failures``, 3 by default); an
exception inside a frame is retried ``retries`` times, then reported. The
task must be a pure function of its inputs: a rerun writes the same files.

Ctrl-C in a terminal reaches the local cluster's workers too (one process
group): they ignore it and this process, which handles it, closes the cluster
(:func:`_local_cluster`). :func:`check_scheduler` tells before any work
whether a scheduler answers at an address.

A frame's numbers must not depend on where it runs: frame functions fit
inside :func:`~polarbssrdf._threads.one_blas_thread`, BLAS on one thread as
in a Dask worker, so a frame fitted here equals the one fitted on a worker bit
for bit (:mod:`polarbssrdf._threads` says why it matters).
"""

from __future__ import annotations

import asyncio
import logging
import signal
import sys
import threading
import uuid

from tqdm import tqdm

from polarbssrdf.errors import CommandError, option

SCHEDULER_TIMEOUT_S = 5.0
"""How long :func:`check_scheduler` waits for a scheduler to answer."""


def _reason(error):
    return f"{type(error).__name__}: {error}"


def run_frames(task, frames, *, workers=None, scheduler=None, retries=1, progress=True,
               description="frames"):
    """``(records, failures)`` of ``task`` over ``frames`` (see the module docstring)."""

    frames = list(frames)
    records, failures = {}, {}
    with tqdm(total=len(frames), desc=description, unit="frame", disable=not progress) as bar:
        if workers is None and scheduler is None:
            for frame in frames:
                try:
                    records[frame] = task(frame)
                except (ValueError, OSError, RuntimeError) as error:
                    failures[frame] = _reason(error)
                bar.update()
            return records, failures
        # Dask (0.5 s to import) only when frames go to a cluster
        from dask.distributed import Client, as_completed

        cluster = None
        if scheduler is None:
            cluster = _local_cluster(int(workers))
        client = Client(cluster if cluster is not None else scheduler)
        try:
            token = uuid.uuid4().hex[:8]  # a rerun must not reuse an earlier run's results
            futures = {client.submit(task, frame, key=f"{description}-f{frame:04d}-{token}",
                                     retries=retries, pure=False): frame for frame in frames}
            for future in as_completed(futures):
                frame = futures[future]
                try:
                    records[frame] = future.result()
                except Exception as error:  # noqa: BLE001 - reported per frame, the rest go on
                    failures[frame] = _reason(error)
                bar.update()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    return records, failures


_TRACKER_WARNING = "ignore:resource_tracker:UserWarning"


def _local_cluster(workers):
    """A LocalCluster of ``workers`` single-threaded processes that leave Ctrl-C to us.

    A terminal sends Ctrl-C to the whole process group, workers included, and each
    worker printed its own tracebacks (67 lines with two) before our one line. Workers
    are started with SIGINT ignored (an ignored signal stays ignored in the spawned
    interpreter) and :func:`dask_setup` ignores it again in any worker started later
    (a nanny's restart); this process catches Ctrl-C and closes the cluster, which
    stops them.
    """
    from dask.distributed import LocalCluster  # deferred, as in run_frames

    # A worker killed mid-frame (after Ctrl-C it is busy in a kernel) leaves its semaphores
    # to multiprocessing's resource tracker, which removes them and says so in a warning
    # after our last line. The tracker starts with this process's warning options.
    if _TRACKER_WARNING not in sys.warnoptions:
        sys.warnoptions.append(_TRACKER_WARNING)
    previous = signal.getsignal(signal.SIGINT)
    in_main_thread = threading.current_thread() is threading.main_thread()
    if in_main_thread:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=":0", silence_logs=40, preload=[__name__])
    finally:
        if in_main_thread:
            signal.signal(signal.SIGINT, previous)


def _not_a_heartbeat_failure(record) -> bool:
    return "during heartbeat" not in record.getMessage()


def dask_setup(worker) -> None:
    """Dask's preload hook, run in each worker process of :func:`_local_cluster`: Ctrl-C is
    the parent's to handle, and a heartbeat that finds the scheduler gone is not an error
    worth a traceback.

    After Ctrl-C this process closes the cluster; a worker whose heartbeat was under way
    then logged "Failed to communicate with scheduler during heartbeat" at ERROR with a
    20-line traceback after our one line (seen once in a clean-clone test run,
    2026-12-02). A heartbeat that fails while the cluster runs is retried by the worker,
    and a worker that is lost shows as its frame's error in this process."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.getLogger("distributed.worker").addFilter(_not_a_heartbeat_failure)


def check_scheduler(address, timeout=None) -> None:
    """Connect to the Dask scheduler at ``address`` and hang up, before any stage starts:
    a :class:`CommandError` naming the address when nothing answers within ``timeout`` s
    (default :data:`SCHEDULER_TIMEOUT_S`).

    Dask's comm layer does the handshake (a plain ``Client`` would leave a half-made
    client whose clean-up at exit prints a traceback).
    """
    from distributed.comm import connect  # deferred, as in run_frames

    timeout = SCHEDULER_TIMEOUT_S if timeout is None else timeout

    async def probe():
        comm = await connect(address, timeout=timeout)
        await comm.close()

    try:
        asyncio.run(probe())
    except ValueError as error:  # e.g. "missing port number in address 'host'"
        raise CommandError(f"{option('scheduler')} {address!r} is not a Dask scheduler address ({error}); "
                           "give one like tcp://10.0.0.1:8786") from None
    except (OSError, asyncio.TimeoutError) as error:
        raise CommandError(f"no Dask scheduler answers at {address} ({error}): start one there "
                           f"('dask scheduler', then 'dask worker {address}' on each machine) "
                           f"or drop {option('scheduler')} to run the frames here") from None


def scheduling_overhead(records, wall_seconds, workers):
    """Share of the wall time not spent inside frames: ``1 - sum(frame s) / (workers x wall)``."""
    busy = sum(float(r.get("seconds", 0.0)) for r in records.values())
    return max(0.0, 1.0 - busy / (max(int(workers), 1) * max(wall_seconds, 1e-9)))

