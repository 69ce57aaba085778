"""Programs declared below the callers, compiled by the caller layer.

The modules under ``model/``, ``controllers/`` and ``plant/`` call a few programs of their own
(the start pose's solve and the effective mass of a plant, ``check_start``'s det Ĵ, the force-rate
design's poses and measures, the robust laws' sizing) and :class:`hinfnn.controllers.SampledController`
compiles the robot loop's update. They do not compile them: the compile machinery
(:mod:`hinfnn._programs`, :mod:`hinfnn._loop`, :mod:`hinfnn._cache`) is the callers'
(docs/architecture.md, "Writing code the loop runs", rule 8). They declare what each program is,
and :mod:`hinfnn.compiled` decides how it is compiled:

* :func:`setup_program` ``("name")``: a program every process of an arm runs once at setup,
  compiled by :func:`hinfnn.compiled.compile_declared` as ``hinfnn._programs.kept("name")``
  (kept traced and lowered on disk between processes; on arms traced by products and compiled with
  the simulator's XLA options);
* :func:`design_program`: a design-time program, compiled as ``hinfnn._programs.jit_by_joints``
  (on arms traced by products, XLA's older loop emitters at LLVM -O0);
* :func:`loop_jit`: a loop program made outside the simulator (the robot loop's update), compiled
  as :func:`hinfnn.compiled.loop_jit` (the simulator's XLA options for the arm's joints).

A declared program is the plain function (``.fn``, also ``__wrapped__``) and its kind; its compiled
form is made by :mod:`hinfnn.compiled` at its first call (``.compiled``), once per process, and
every call goes to it: the same compiled program, with the same numbers, as the decorator applied
where the function is defined. :mod:`hinfnn.compiled` is found by name at that first call
(:func:`importlib.import_module`, as the package root names everything lazily): the one reference
of this layer to the caller layer, so that the functions' modules import nothing above them.
"""

from __future__ import annotations

import functools
import importlib
import threading

#: The kinds of declared programs (what :func:`hinfnn.compiled.compile_declared` compiles them as).
KINDS = ("setup", "design")

_LOCK = threading.Lock()


def _caller():
    """The caller layer's module that compiles declared programs (:mod:`hinfnn.compiled`)."""
    return importlib.import_module("hinfnn.compiled")


class DeclaredProgram:
    """A plain function ``fn`` of model/, controllers/ or plant/ and the kind of program it is
    (:data:`KINDS`; ``name``: a setup program's unique name; ``static_argnames``: a design
    program's static arguments); called, it runs the compiled form the caller layer made of it."""

    def __init__(self, fn, kind: str, name: str | None = None, static_argnames=None):
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        self.fn = fn
        self.kind = kind
        self.name = name
        self.static_argnames = static_argnames
        self._compiled = None
        functools.update_wrapper(self, fn, updated=())

    @property
    def compiled(self):
        """The compiled program (:func:`hinfnn.compiled.compile_declared`), made at the first use."""
        if self._compiled is None:
            with _LOCK:  # the groups of a batch are compiled side by side on threads
                if self._compiled is None:
                    self._compiled = _caller().compile_declared(self)
        return self._compiled

    def __call__(self, *args, **kwargs):
        return self.compiled(*args, **kwargs)

    def __repr__(self) -> str:
        return f"<{self.kind} program {self.name or self.fn.__qualname__}>"


def setup_program(name: str):
    """Decorator: the function is a setup program named ``name`` (unique in hinfnn), compiled by
    the caller layer (see the module docstring); its first argument is a plant or an arm."""

    def declare(fn):
        return DeclaredProgram(fn, "setup", name=name)

    return declare


def design_program(fn=None, *, static_argnames=None):
    """Decorator: the function is a design-time program, compiled by the caller layer (see the
    module docstring); its first argument is a plant, an arm or a controller."""
    if fn is None:
        return functools.partial(design_program, static_argnames=static_argnames)
    return DeclaredProgram(fn, "design", static_argnames=static_argnames)


def loop_jit(fn, n_joints: int, **jit_kwargs):
    """``fn`` compiled as a program of the loop of an arm of ``n_joints`` joints
    (:func:`hinfnn.compiled.loop_jit`; ``jit_kwargs`` as :func:`jax.jit`'s)."""
    return _caller().loop_jit(fn, n_joints, **jit_kwargs)


__all__ = ["DeclaredProgram", "KINDS", "design_program", "loop_jit", "setup_program"]
