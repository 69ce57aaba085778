"""Where a sweep's batches run: :class:`LocalBackend` (one after the other in this process, JAX
using the machine's cores) or the Ray backend (:mod:`hinfnn.sweep.ray_backend`, batches as Ray
tasks), picked by name (:func:`make_backend`). Each has the same four methods: ``describe``,
``check`` (the draws, in chunks), ``run`` (the batch jobs) and ``close``."""

from __future__ import annotations

import os

from ..errors import ConfigError
from .worker import check_runs, execute_batch


class LocalBackend:
    """Batches run one after the other in this process (JAX uses the machine's cores)."""

    name = "local"

    def describe(self) -> str:
        return f"local ({os.cpu_count()} cores)"

    def check(self, chunks, on_done):
        for chunk in chunks:
            on_done(check_runs(*chunk))

    def run(self, jobs, on_done, progress):
        for job in jobs:
            on_done(execute_batch(job, progress=lambda f, job=job: progress(job, f)))

    def close(self):
        pass


def make_backend(name: str, address: str | None = None):
    if name == "local":
        if address is not None:
            raise ConfigError("--address is for the ray backend", key="--address")
        return LocalBackend()
    if name == "ray":
        from .ray_backend import RayBackend

        return RayBackend(address=address)
    raise ConfigError(f"must be 'local' or 'ray', got {name!r}", key="--backend")


__all__ = ["LocalBackend", "make_backend"]
