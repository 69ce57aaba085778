"""Where a sweep's batches run: :class:`LocalBackend` (on this machine: batches side by side in
worker processes, one per core, or one after the other in this process) or the Ray backend
(:mod:`hinfnn.sweep.ray_backend`, batches as Ray tasks), picked by name (:func:`make_backend`).
Each has the same four methods: ``describe``, ``check`` (the draws, in chunks), ``run`` (the
batch jobs) and ``close``.

Why processes: XLA's CPU runtime runs one batched program on about one core (a UR5 batch runs
as fast pinned to one core as unpinned, and two such processes side by side each as fast as one
alone: docs/performance.md), and two executions of a program at once in
one process deadlocked in XLA's runtime (tried: threads), so the cores are used by processes.
"""

from __future__ import annotations

import concurrent.futures
import concurrent.futures.process
import multiprocessing
import os
import queue as queue_module

from ..errors import ConfigError, is_integer
from .worker import check_runs, execute_batch, fault_once

#: Seconds between the driver's looks at the workers' progress.
POLL_S = 0.5
#: A worker reports its batch's progress at most this often (fraction of the batch).
PROGRESS_STEP = 0.02


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the platform has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


#: Seconds of simulation in one process from which the local backend, left to choose, starts
#: worker processes: each worker's start (the interpreter, JAX and hinfnn, and its programs found
#: in the compilation cache) costs seconds, a loss for a quick trial.
PROCESSES_FROM_S = 60.0


def per_step_s(n_joints: int) -> float:
    """A rough single-core cost in seconds of one member's RK4 step in a batch, the choice's only
    input: a constant for the two-link arm and one for a 6-DOF arm (from `make bench`'s batch
    rows, docs/performance.md), growing as n²."""
    return 2.5e-6 if n_joints <= 2 else 26e-6 * (n_joints / 6) ** 2


def auto_workers(n_runs: int, n_steps: int, n_joints: int) -> int:
    """The local backend's worker processes for a sweep of ``n_runs`` runs of ``n_steps`` steps on
    an arm of ``n_joints`` joints: one per core when one process would simulate for at least
    :data:`PROCESSES_FROM_S` (by :func:`per_step_s`), else 1 (this process)."""
    cores = available_cores()
    if cores == 1 or n_runs * n_steps * per_step_s(n_joints) < PROCESSES_FROM_S:
        return 1
    return cores


def check_workers(workers) -> int | None:
    """``workers`` as given to the local backend: None (one per core) or a whole number >= 1."""
    if workers is None:
        return None
    if not is_integer(workers) or workers < 1:
        raise ConfigError(f"must be a whole number >= 1, got {workers!r}", key="--workers")
    return int(workers)


# --- the worker processes ---------------------------------------------------------------------------
_progress_queue = None


def _die_with_parent() -> None:
    """Linux: this process is killed when the driver dies, however it dies (a SIGKILL'd sweep
    leaves no worker computing a batch nobody will store)."""
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # not Linux: the pool's pipes close when the driver goes
        pass


def _init_worker(progress_queue, parent: int) -> None:
    global _progress_queue
    _die_with_parent()
    if os.getppid() != parent:  # the driver died before the line above took effect
        os._exit(1)
    from .._config import configure

    configure()  # float64 and the compilation cache in $HINFNN_CACHE_DIR (inherited)
    _progress_queue = progress_queue


def _check_in_worker(chunk):
    return check_runs(*chunk)


def _run_in_worker(job):
    fault_once()
    last = [-1.0]

    def progress(fraction):
        if _progress_queue is not None and (fraction - last[0] >= PROGRESS_STEP or fraction >= 1.0):
            last[0] = fraction
            _progress_queue.put((job.batch.id, fraction))

    return execute_batch(job, progress=progress)


class LocalBackend:
    """Batches on this machine: with ``workers`` > 1, side by side in that many worker processes
    (started once, on the first check, with ``spawn``; each configures JAX as ``hinfnn`` does and
    finds the programs in the compilation cache), else one after the other in this process.
    None: one worker per core this process may use (:func:`hinfnn.sweep.run.run_sweep` decides by
    :func:`auto_workers` first). A batch's numbers do not depend on where it runs (the same
    program, the same members)."""

    name = "local"

    def __init__(self, workers: int | None = None):
        workers = check_workers(workers)
        self.workers = available_cores() if workers is None else workers
        self._pool = None
        self._queue = None

    @property
    def parallel(self) -> int:
        """How many batches run at once, all in this machine's memory (the plan's ``parallel`` and
        ``share``)."""
        return self.workers

    share = parallel

    def describe(self) -> str:
        if self.workers == 1:
            return f"local (this process, {available_cores()} cores)"
        return f"local ({self.workers} worker processes, {available_cores()} cores)"

    def _start(self):
        if self._pool is None:
            ctx = multiprocessing.get_context("spawn")  # JAX's threads make fork unsafe
            self._queue = ctx.Queue()
            self._pool = concurrent.futures.ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_init_worker,
                                                                initargs=(self._queue, os.getpid()))
        return self._pool

    def check(self, chunks, on_done):
        if self.workers == 1 or len(chunks) == 1:
            for chunk in chunks:
                on_done(check_runs(*chunk))
            return
        pool = self._start()
        self._gather([pool.submit(_check_in_worker, chunk) for chunk in chunks], on_done)

    def run(self, jobs, on_done, progress):
        if self.workers == 1 or len(jobs) == 1:
            for job in jobs:
                on_done(execute_batch(job, progress=lambda f, job=job: progress(job, f)))
            return
        pool = self._start()
        by_id = {job.batch.id: job for job in jobs}
        finished = set()

        def done(res):
            finished.add(res["batch"])
            on_done(res)

        def poll():  # a report that arrives after its batch's result is dropped
            while True:
                try:
                    batch, fraction = self._queue.get_nowait()
                except queue_module.Empty:
                    return
                if batch in by_id and batch not in finished:
                    progress(by_id[batch], fraction)

        self._gather([pool.submit(_run_in_worker, job) for job in jobs], done, poll)

    def _gather(self, pending, on_done, poll=None):
        """``on_done`` with each result as it arrives (in the driver, in the order they finish);
        an error in a worker, a worker that died (killed, out of memory) or an interrupt of the
        driver stops the workers and is raised: the batches in flight are lost, as with a killed
        sweep (``--resume`` runs them)."""
        try:
            pending = set(pending)
            while pending:
                ready, pending = concurrent.futures.wait(pending, timeout=POLL_S,
                                                         return_when=concurrent.futures.FIRST_COMPLETED)
                for fut in ready:
                    try:
                        res = fut.result()  # raises the worker's error
                    except concurrent.futures.process.BrokenProcessPool as err:
                        raise RuntimeError("a worker process of the local backend died while running a batch "
                                           "(killed, or out of memory?); the finished batches are saved and "
                                           "--resume runs the others") from err
                    on_done(res)
                if poll is not None:
                    poll()
        except BaseException:
            self._stop()
            raise

    def _stop(self):
        """End the workers now (an error or an interrupt): the executor has no public way to end
        running tasks, so its processes are terminated."""
        if self._pool is not None:
            processes = list(getattr(self._pool, "_processes", {}).values())
            self._pool.shutdown(wait=False, cancel_futures=True)
            for proc in processes:
                proc.terminate()
            for proc in processes:
                proc.join(10)
            self._pool = None

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


def check_options(name: str, address: str | None = None, workers: int | None = None) -> None:
    """The backend's options, checked before anything starts (the CLI calls it before it touches
    the output folder; :func:`make_backend` before it builds the backend)."""
    if name not in ("local", "ray"):
        raise ConfigError(f"must be 'local' or 'ray', got {name!r}", key="--backend")
    if address is not None and name != "ray":
        raise ConfigError("only with --backend ray (the Ray cluster to join)", key="--address")
    if name == "ray":
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            raise ConfigError("the ray backend needs Ray: pip install 'hinfnn[ray]'", key="--backend")
        if address is not None:
            check_address(address)
    if workers is not None:
        if name != "local":
            raise ConfigError("only with the local backend (Ray runs one task per CPU)", key="--workers")
        check_workers(workers)


#: What ``--address`` accepts, in words.
ADDRESSES = ("'auto' (the cluster this machine belongs to), HOST:PORT (a cluster's head, e.g. 10.0.0.5:6379) "
             "or ray://HOST:PORT (a remote cluster through Ray Client, e.g. ray://10.0.0.5:10001)")


def check_address(address: str) -> None:
    """``--address`` checked before anything starts (Ray itself would say so only as a bare
    ``ValueError`` once the sweep's folder is made): ``auto``, ``HOST:PORT`` or ``ray://HOST:PORT``
    with a port from 1 to 65535; ``ray://`` needs Ray Client (``pip install 'ray[client]'``)."""
    import importlib.util

    if address == "auto":
        return
    rest = address[len("ray://"):] if address.startswith("ray://") else address
    host, colon, port = rest.rpartition(":")
    if not (colon and host and "/" not in rest and port.isdigit() and 1 <= int(port) <= 65535):
        raise ConfigError(f"must be {ADDRESSES}, got {address!r}", key="--address")
    if address.startswith("ray://") and importlib.util.find_spec("grpc") is None:
        raise ConfigError(f"{address!r} joins through Ray Client, which needs pip install 'ray[client]' "
                          "(or run the sweep on a node of the cluster with --address auto)", key="--address")


def make_backend(name: str, address: str | None = None, workers: int | None = None):
    check_options(name, address, workers)
    if name == "local":
        return LocalBackend(workers)
    from .ray_backend import RayBackend

    return RayBackend(address=address)


__all__ = ["LocalBackend", "auto_workers", "available_cores", "check_address", "check_options", "make_backend"]
