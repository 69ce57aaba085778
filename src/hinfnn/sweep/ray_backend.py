"""The Ray backend: each batch is one Ray task on one worker, results streamed back as they finish.

``hinfnn sweep SPEC --backend ray`` starts a local Ray instance (all the machine's cores, one
task per core), or with ``--address`` joins an existing cluster (``auto``: the cluster this
machine belongs to, ``ray://HEAD:10001``: a remote one through Ray Client). The driver checks the
draws (as tasks too), plans the batches and writes the Parquet parts; each task builds its
members from the base scenario and their values, runs :func:`hinfnn.simulate_batch` and returns
the rows. A task lost with its worker (the node died, the process was killed) is retried up to
:data:`MAX_RETRIES` times; an error raised inside a task stops the sweep (it would fail again).

Workers call :func:`hinfnn.configure` (float64 and the compilation cache in
``$HINFNN_CACHE_DIR``, which the driver passes on). On a remote cluster the driver's ``hinfnn``
package is shipped with the tasks (Ray's ``py_modules``), so the nodes need only its
dependencies (``pip install 'hinfnn[ray]'`` in the cluster's image). Ray is imported only here.
"""

from __future__ import annotations

import logging
import os
import warnings

from ..errors import ConfigError
from .worker import fault_once

#: Retries of a task whose worker died (Ray's ``max_retries``).
MAX_RETRIES = 3
#: Seconds between progress polls of the tasks in flight.
POLL_S = 1.0
_ENV = ("HINFNN_CACHE_DIR", "XDG_CACHE_HOME", "XLA_FLAGS", "JAX_PLATFORMS")

_configured = False


def _configure_worker():
    global _configured
    if not _configured:
        from .._config import configure

        configure()
        _configured = True


def _check_task(chunk):
    from .worker import check_runs

    _configure_worker()
    return check_runs(*chunk)


def _run_task(job, reporter=None):
    from .worker import execute_batch

    fault_once()
    _configure_worker()
    last = [-1.0]

    def progress(fraction):
        if reporter is not None and fraction - last[0] >= 0.02:
            last[0] = fraction
            reporter.set.remote(job.batch.id, fraction)

    return execute_batch(job, progress=progress)


class _Reporter:
    """A small actor the tasks tell their progress to (fraction of their batch done)."""

    def __init__(self):
        self.fractions = {}

    def set(self, batch, fraction):
        self.fractions[batch] = fraction

    def get(self):
        return dict(self.fractions)


class RayBackend:
    """Batches as Ray tasks (one CPU each) on a local instance or an existing cluster."""

    name = "ray"

    def __init__(self, address: str | None = None, max_retries: int = MAX_RETRIES):
        try:
            import ray
        except ImportError:
            raise ConfigError("the ray backend needs Ray: pip install 'hinfnn[ray]'", key="--backend") from None
        self.ray = ray
        self.started = False
        address = address or "local"
        if not ray.is_initialized():
            env = {k: os.environ[k] for k in _ENV if k in os.environ}
            runtime_env = {"env_vars": env} if env else {}
            if address != "local":
                import hinfnn

                runtime_env["py_modules"] = [os.path.dirname(hinfnn.__file__)]
            try:
                with warnings.catch_warnings():
                    # Ray starts its processes with fork + exec, which JAX's fork hook warns about
                    # (the child runs no JAX code: it execs at once)
                    warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
                    ray.init(address=address, include_dashboard=False,
                             logging_level=logging.ERROR if address == "local" else logging.WARNING,
                             runtime_env=runtime_env or None)
            except ConnectionError as err:
                raise ConfigError(f"cannot reach a Ray cluster at {address!r}: {err}", key="--address") from None
            self.started = True
        self.address = address
        self.check_remote = ray.remote(num_cpus=1, max_retries=max_retries)(_check_task)
        self.run_remote = ray.remote(num_cpus=1, max_retries=max_retries)(_run_task)
        self.reporter_cls = ray.remote(num_cpus=0)(_Reporter)

    def cpus(self) -> int:
        return int(self.ray.cluster_resources().get("CPU", 0))

    @property
    def parallel(self) -> int:
        """How many batches run at once: one task per CPU (the plan cuts a group into that many)."""
        return max(1, self.cpus())

    @property
    def share(self) -> int:
        """How many batches share the driver machine's memory: all, on a local instance; on a
        cluster the nodes' memory is Ray's to place (the plan's cap is the driver's memory)."""
        return self.parallel if self.address == "local" else 1

    def describe(self) -> str:
        where = "local instance" if self.address == "local" else f"cluster {self.address}"
        return f"ray ({where}, {self.cpus()} CPUs)"

    def _gather(self, refs: dict, on_done, poll=None):
        """Wait for every task, calling ``on_done`` with each result as it arrives; the tasks
        left are cancelled if one fails or the driver is interrupted."""
        ray = self.ray
        try:
            while refs:
                ready, _ = ray.wait(list(refs), num_returns=1, timeout=POLL_S)
                for ref in ready:
                    refs.pop(ref)
                    on_done(ray.get(ref))
                if poll is not None and refs:
                    poll()
        except BaseException:
            for ref in refs:
                try:
                    ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001 - best effort
                    pass
            raise

    def check(self, chunks, on_done):
        refs = {self.check_remote.remote(chunk): i for i, chunk in enumerate(chunks)}
        self._gather(refs, on_done)

    def run(self, jobs, on_done, progress):
        reporter = self.reporter_cls.remote()
        refs = {self.run_remote.remote(job, reporter): job for job in jobs}

        def poll():
            fractions = self.ray.get(reporter.get.remote())
            for job in list(refs.values()):
                f = fractions.get(job.batch.id)
                if f is not None:
                    progress(job, f)

        try:
            self._gather(refs, on_done, poll)
        finally:
            try:
                self.ray.kill(reporter)
            except Exception:  # noqa: BLE001
                pass

    def close(self):
        if self.started:
            self.ray.shutdown()
            self.started = False


__all__ = ["RayBackend", "MAX_RETRIES"]
