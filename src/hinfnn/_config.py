"""Process-wide JAX settings, set only when asked: :func:`configure` (the ``hinfnn`` command
calls it) and the float64 check of the entry points that compute (:func:`require_x64`).

``import hinfnn`` changes nothing in the process: the platform is JAX's own choice (a GPU is
used when JAX finds one), float64 and the persistent compilation cache are turned on by
:func:`configure`.
"""

from __future__ import annotations


def configure(*, x64: bool = True, cache: bool = True, async_dispatch: bool | None = None):
    """Set JAX up for hinfnn in this process: float64 (hinfnn's numbers are float64 throughout;
    ``x64=False`` leaves JAX's setting alone) and the persistent compilation cache in the folder
    the environment gives (``HINFNN_CACHE_DIR``, see :mod:`hinfnn._cache`; ``cache=False``
    leaves it off). ``async_dispatch=False``: JAX's CPU async dispatch off, the setting of a
    process that runs a robot loop (:class:`hinfnn.SampledLoop`): every compiled call then runs on
    the calling thread, where with it on (JAX's default, ``None`` leaves it) a program above 1,000
    flops is handed to a worker thread and back, which costs a robot loop's update more than its
    arithmetic (docs/performance.md). Call it once, before the first computation. Returns the cache
    folder in use, or None."""
    import jax

    if x64:
        jax.config.update("jax_enable_x64", True)
    if async_dispatch is not None:
        jax.config.update("jax_cpu_enable_async_dispatch", bool(async_dispatch))
    if cache:
        from . import _cache

        return _cache.setup_from_env()
    return None


def require_x64() -> None:
    """Raise :class:`~hinfnn.errors.ConfigError` unless JAX computes in float64 (the controller's
    gains and the contact's stiffness span 10 decades: float32 results are not hinfnn's)."""
    import jax

    if not jax.config.jax_enable_x64:
        from .errors import ConfigError

        raise ConfigError("hinfnn computes in float64: call hinfnn.configure() once before running "
                          "(or set JAX_ENABLE_X64=1 in the environment)")
