"""Process-wide JAX settings hinfnn relies on (float64 on the CPU, persistent compilation cache).

Imported first by ``hinfnn/__init__.py`` so that every array the library creates is float64 and
every program it compiles can be reused by the next process (see :mod:`hinfnn._cache`;
``HINFNN_CACHE_DIR=off`` turns that off).
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from . import _cache  # noqa: E402

_cache.setup_from_env()  # never raises; an unusable folder means no cache and one warning
