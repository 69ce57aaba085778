"""Compiled programs kept traced and lowered on disk, so that a new process skips both.

A run's chunk program (:mod:`hinfnn.sim.simulate`) is traced (Python walks the plant, the
controller and RK4: seconds for a 6-DOF arm) and lowered to StableHLO in every process that runs it,
even when JAX's persistent compilation cache then finds the compiled code. :class:`ExportedProgram`
keeps the lowered program itself (:func:`jax.export.export`, serialised) in the compilation cache's
folder (:func:`hinfnn.cache_dir`), keyed by everything that decides it:

* the hinfnn source (a digest of every module of the package), JAX's and jaxlib's versions,
  ``XLA_FLAGS``, float64 and the backend;
* the program's own settings (its name, the batch axes, the record slots, sampled or continuous
  control, the stored fields, the loop options);
* the structure of its arguments (the pytree structure, static fields included) and every leaf's
  shape, dtype and weak type.

A later process with the same key loads it and calls it (``Exported.call``: nothing of hinfnn is
traced; XLA's compilation is then found in the persistent cache), with the same numbers bit for bit
(tests/test_cache.py). :class:`KeptFunction` does the same for any function of pytrees whose result
is arrays in plain containers (the start pose's solve, the scenario's path check, the final state:
``kept``); :class:`ExportedProgram` is its form for a chunk. Programs that cannot be exported (a plant stepped by a host callback, such
as MuJoCo) are traced as usual, and remembered as such. With the cache off
(``HINFNN_CACHE_DIR=off``) everything is traced as usual.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from pathlib import Path

import jax

#: File names of the exported programs in the cache folder (:data:`hinfnn._cache` owns them).
PREFIX = "hinfnn-program-"
SUFFIX = "-export"


@functools.cache
def source_digest() -> str:
    """A digest of every module of the hinfnn package (its code decides what a program is)."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _environment() -> tuple:
    import jaxlib

    return (source_digest(), jax.__version__, jaxlib.__version__, os.environ.get("XLA_FLAGS", ""),
            bool(jax.config.jax_enable_x64), jax.default_backend())


def _leaf_spec(x) -> tuple:
    """(shape, dtype, weakly typed) of an argument leaf (a Python number is weakly typed)."""
    if isinstance(x, (bool, int, float, complex)):
        return (), str(jax.numpy.asarray(x).dtype), True
    return tuple(x.shape), str(x.dtype), bool(getattr(x, "weak_type", False))


class KeptFunction:
    """``fn`` (a function of pytrees whose result is arrays in tuples, lists or dicts) jit-compiled,
    with its lowered form kept on disk between processes (see the module docstring): the setup
    programs every process of an arm runs once (the start pose's Newton solve, the path checks, the
    final state), whose tracing was most of a warm UR5 ``hinfnn run``'s time before the chunk.
    ``settings``: what else decides the program (hashable, its repr part of the key);
    ``compiler_options``: XLA's compile options (None: XLA's defaults), part of the key. Called
    inside another trace, it is ``jax.jit(fn)`` as usual."""

    def __init__(self, fn, name: str, settings=None, compiler_options: dict | None = None):
        self.fn = fn
        self.name = name
        self.compiler_options = dict(compiler_options) if compiler_options else None
        self.settings = (settings, sorted((self.compiler_options or {}).items()))
        self.jitted = jax.jit(fn, compiler_options=self.compiler_options)
        self._entries: dict = {}
        functools.update_wrapper(self, fn, updated=())

    # --- the key and the files ---------------------------------------------------------------------
    def _key(self, treedef, leaves) -> str:
        text = repr((_environment(), self.name, self.settings, str(treedef), [_leaf_spec(x) for x in leaves]))
        return hashlib.sha256(text.encode()).hexdigest()

    def _path(self, key: str) -> Path | None:
        from ._cache import cache_dir

        folder = cache_dir()
        return None if folder is None else folder / f"{PREFIX}{self.name}-{key}{SUFFIX}"

    # --- calling -------------------------------------------------------------------------------------
    def __call__(self, *args):
        leaves, treedef = jax.tree.flatten(args)
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return self.jitted(*args)
        entry = self._entry(leaves, treedef)
        if entry is None:
            return self.jitted(*args)
        return self._output(args, entry, entry[0](*[_committed(x) for x in leaves]))

    def _output(self, args, entry, out):
        """What a call returns from what the kept program returned."""
        return out

    def _flat(self, treedef, meta: dict):
        """The function of the arguments' leaves that is exported (``meta``: what to keep with it)."""

        def flat(*xs):
            return self.fn(*jax.tree.unflatten(treedef, xs))

        return flat

    def _entry(self, leaves, treedef):
        """(the compiled call on flat leaves, the kept metadata, the output avals), or None to trace."""
        key = self._key(treedef, leaves)
        if key in self._entries:
            return self._entries[key]
        path = self._path(key)
        entry = None
        if path is not None:
            entry = self._load(path) if path.exists() else self._export(path, leaves, treedef)
        self._entries[key] = entry
        return entry

    def _load(self, path: Path):
        try:
            blob = path.read_bytes()
            size = int.from_bytes(blob[:8], "little")
            meta = json.loads(blob[8:8 + size])
            if not meta.get("exportable", True):
                return None
            exported = jax.export.deserialize(bytearray(blob[8 + size:]))
        except Exception:  # noqa: BLE001 - a truncated or foreign file: trace as usual
            return None
        return jax.jit(exported.call, compiler_options=self.compiler_options), meta, exported.out_avals

    def _export(self, path: Path, leaves, treedef):
        meta: dict = {"exportable": True, "name": self.name}
        flat = self._flat(treedef, meta)
        flat.__name__ = flat.__qualname__ = self.name  # what a trace of it is called
        specs = [jax.ShapeDtypeStruct(shape, dtype, weak_type=weak) for shape, dtype, weak in map(_leaf_spec, leaves)]
        try:
            exported = jax.export.export(jax.jit(flat))(*specs)
            payload = exported.serialize()
        except Exception:  # noqa: BLE001 - not exportable (a host callback): trace as usual from now on
            _write(path, {"exportable": False}, b"")
            return None
        _write(path, meta, payload)
        return jax.jit(exported.call, compiler_options=self.compiler_options), meta, exported.out_avals

    def lower_ahead(self, *args):
        """The kept program lowered for the call ``self(*args)`` would make (``args`` may hold
        ``jax.ShapeDtypeStruct`` in place of arrays; nothing runs), or None when the program is not
        kept (the cache is off, or it cannot be exported: that call traces and compiles it). Its
        ``.compile()``, which holds no Python lock while XLA compiles, then leaves that call nothing
        to compile: the arrays the call commits (:func:`_committed`) are given their device here, so
        that the call finds this compiled program in JAX's own cache (tested)."""
        leaves, treedef = jax.tree.flatten(args)
        entry = self._entry(leaves, treedef)
        if entry is None:
            return None
        arrays = [x for x in leaves if isinstance(x, jax.Array)]
        device = next(iter(arrays[0].devices())) if arrays else jax.local_devices()[0]
        placed = jax.sharding.SingleDeviceSharding(device)
        specs = [jax.ShapeDtypeStruct(shape, dtype, weak_type=weak,
                                      sharding=placed if isinstance(x, (jax.Array, jax.ShapeDtypeStruct)) else None)
                 for x, (shape, dtype, weak) in zip(leaves, map(_leaf_spec, leaves))]
        return entry[0].lower(*specs)


#: XLA options added, for an arm of 3 or more joints, to those of the simulator
#: (:func:`jit_by_joints`): LLVM's optimisation level 0. A design's programs run a few times each
#: and are compiled once, so their compile time is their cost: the same printed design (the UR5's
#: loop Jacobian to 7e-16), compiled in less time, the programs slower to run.
ANALYSIS_OPTIONS = {"xla_backend_optimization_level": 0}


def _by_products(fn):
    """``fn`` traced with a URDF chain's kinematics by array products: every object of its
    arguments holds its kernels with ``products`` (:meth:`hinfnn._linalg.Kernels.hold`)."""
    from ._linalg import hold

    @functools.wraps(fn)
    def traced(*args, **kwargs):
        return fn(*hold(args, _with_products), **kwargs)

    return traced


def _with_products(kernels):
    """``kernels`` with a URDF chain's kinematics by products (:attr:`hinfnn._linalg.Kernels.products`)."""
    return kernels.replace(products=True)


def jit_by_joints(fn=None, *, static_argnames=None):
    """Decorator for design-time programs: ``jax.jit(fn)``, compiled with the XLA options the
    simulator uses for the joints of its first argument (a plant or an arm, ``.n``;
    :meth:`hinfnn._loop.LoopOptions.compiler_options`) and :data:`ANALYSIS_OPTIONS`: for arms of 3
    or more joints XLA's older loop emitters (its default emitters compile the rigid-body
    algorithms written out for fusion several times slower; the same matrix to 3e-16) and no LLVM
    optimisation, and traced with a URDF chain's kinematics by array products
    (:attr:`hinfnn._linalg.Kernels.products`: the layout written for the compiled loop is a third of the
    loop Jacobian's program); XLA's defaults for the two-link arm. Called inside another trace, it is ``jax.jit(fn)``."""
    if fn is None:
        return functools.partial(jit_by_joints, static_argnames=static_argnames)
    from ._loop import ROLL_FROM_JOINTS, LoopOptions

    plain = jax.jit(fn, static_argnames=static_argnames)
    options = {**(LoopOptions().compiler_options(ROLL_FROM_JOINTS) or {}), **ANALYSIS_OPTIONS}
    arm = jax.jit(_by_products(fn), static_argnames=static_argnames, compiler_options=options)
    return _by_joints(fn, plain, arm)


def kept(name: str):
    """Decorator: :class:`KeptFunction` of the function, under ``name`` (unique in hinfnn), chosen
    by the joints of its first argument (a plant or an arm, ``.n``): for an arm of 3 or more joints
    traced by array products (:attr:`hinfnn._linalg.Kernels.products`) and compiled with XLA's older
    loop emitters, as the simulator's programs (they compile faster so; the same start poses, or
    one ulp off). Not at LLVM -O0 as the design's programs: a sweep checks every draw with them,
    and -O0 would make each check slower to run. XLA's defaults for the two-link arm."""
    from ._loop import ROLL_FROM_JOINTS, LoopOptions

    def decorate(fn):
        options = LoopOptions().compiler_options(ROLL_FROM_JOINTS)
        return _by_joints(fn, KeptFunction(fn, name), KeptFunction(_by_products(fn), name, compiler_options=options))

    return decorate


def _by_joints(fn, plain, arm):
    """``fn``'s two compiled forms as one function: ``arm`` when the design kernels of its first
    argument's joints (a plant or an arm, ``.n``; :meth:`hinfnn._linalg.Kernels.design`) trace a
    chain by products (3 or more joints), else ``plain`` (both kept as the attributes ``.plain``
    and ``.arm``)."""
    from ._linalg import Kernels

    @functools.wraps(fn)
    def call(first, *args, **kwargs):
        return (arm if Kernels.design(getattr(first, "n", 0)).products else plain)(first, *args, **kwargs)

    call.plain, call.arm = plain, arm
    return call


class ExportedProgram(KeptFunction):
    """A simulation chunk: ``fn`` returns ``(carry, records)``, the carry of the same structure as
    argument ``carry_arg``, the records a dict of arrays; kept as :class:`KeptFunction` is, with the
    carry's leaves and the records (by their sorted names) as one flat list of outputs."""

    def __init__(self, fn, name: str, settings, carry_arg: int, compiler_options: dict | None = None):
        super().__init__(fn, name, settings, compiler_options)
        self.carry_arg = carry_arg

    def _flat(self, treedef, meta: dict):
        def flat(*xs):
            carry, records = self.fn(*jax.tree.unflatten(treedef, xs))
            meta["records"] = keys = sorted(records)
            return [*jax.tree.leaves(carry), *(records[k] for k in keys)]

        return flat

    def _output(self, args, entry, out):
        carry_def = jax.tree.structure(args[self.carry_arg])
        n = carry_def.num_leaves
        return jax.tree.unflatten(carry_def, out[:n]), dict(zip(entry[1]["records"], out[n:]))

    def eval_shape(self, *args):
        """The shapes of what a call returns (from the kept program, else by tracing)."""
        entry = self._entry(*jax.tree.flatten(args))
        if entry is None:
            return jax.eval_shape(self.jitted, *args)
        structs = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in entry[2]]
        return self._output(args, entry, structs)


def _committed(x):
    """``x`` committed to its device. ``Exported.call`` returns committed arrays, and ``jax.jit``
    compiles a second program for the same function when an argument once uncommitted (the first
    chunk's carry, from a jitted initialiser) comes back committed (every later chunk's carry):
    a run of more than one chunk compiled its chunk program twice until
    every JAX array was committed before the call. NumPy arrays and Python numbers stay as they are
    (they are the same kind at every call)."""
    if isinstance(x, jax.Array) and not x.committed:
        return jax.device_put(x, next(iter(x.devices())))
    return x


def _write(path: Path, meta: dict, payload: bytes) -> None:
    """The file, written atomically (a process killed meanwhile leaves at most a temporary file,
    which ``hinfnn cache --clear`` removes)."""
    head = json.dumps(meta).encode()
    data = len(head).to_bytes(8, "little") + head + bytes(payload)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError:  # a read-only or vanished cache folder: the program is simply not kept
        tmp.unlink(missing_ok=True)


__all__ = ["ExportedProgram", "KeptFunction", "kept", "source_digest"]
