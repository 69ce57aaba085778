"""Process-wide JAX settings hinfnn relies on (float64 on the CPU).

Imported first by ``hinfnn/__init__.py`` so that every array the library creates is float64.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
