"""MuJoCo's step as an XLA FFI custom call with a stable name (``hinfnn_mujoco_step``,
``hinfnn_mujoco_init``), so that a compiled program that steps MuJoCo can be written to and read
from JAX's persistent compilation cache like any other (docs/mujoco.md, "How the loop runs").

A program that calls Python through :func:`jax.pure_callback` (or JAX's internal Python-callback
custom call) embeds a pointer into this process's table of Python callbacks: JAX never caches it,
and every process compiles it again (a UR5 run's chunk program takes minutes). An FFI
custom call names its handler instead; XLA finds the handler by that name in the process that runs
the program. Here the handler is a :mod:`ctypes` function (XLA's C API for FFI handlers, read
with ctypes structures mirroring ``xla/ffi/api/c_api.h``, API version 0.3) that hands the input
and output buffers to :meth:`hinfnn.plant.mujoco.engine._Family.host_step` as NumPy arrays. The
MuJoCo model a row is stepped with is named by the row itself (its member key), so the program
holds no model: a cached program steps whatever models the running process has built.

:func:`register` registers both targets once per process (before any program that uses them is
traced, compiled or loaded from the cache); :func:`call` is the traced call. Uses only public JAX
API (``jax.ffi.register_ffi_target``, ``jax.ffi.pycapsule``, ``jax.ffi.ffi_call``) and XLA's
stable FFI C ABI.
"""

from __future__ import annotations

import ctypes as C
import threading
import traceback

import jax
import numpy as np

#: The targets' names (part of every compiled program that steps MuJoCo).
TARGETS = {"step": "hinfnn_mujoco_step", "init": "hinfnn_mujoco_init"}

_F64 = 12  # XLA_FFI_DataType_F64
_EXECUTE = 3  # XLA_FFI_ExecutionStage_EXECUTE
_METADATA = 1  # XLA_FFI_Extension_Metadata
_INTERNAL = 13  # XLA_FFI_Error_Code_INTERNAL


class _ExtBase(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("type", C.c_int), ("next", C.c_void_p)]


class _ApiVersion(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p), ("major_version", C.c_int),
                ("minor_version", C.c_int)]


class _Metadata(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("api_version", _ApiVersion), ("traits", C.c_uint32),
                ("state_type_id", C.c_int64)]


class _MetadataExtension(C.Structure):
    _fields_ = [("extension_base", _ExtBase), ("metadata", C.POINTER(_Metadata))]


class _Buffer(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p), ("dtype", C.c_int),
                ("data", C.c_void_p), ("rank", C.c_int64), ("dims", C.POINTER(C.c_int64))]


class _List(C.Structure):  # XLA_FFI_Args, XLA_FFI_Rets (and the layout of XLA_FFI_Attrs)
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p), ("size", C.c_int64),
                ("types", C.c_void_p), ("items", C.POINTER(C.c_void_p))]


class _Attrs(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p), ("size", C.c_int64),
                ("types", C.c_void_p), ("names", C.c_void_p), ("attrs", C.c_void_p)]


class _CallFrame(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.POINTER(_ExtBase)), ("api", C.c_void_p),
                ("ctx", C.c_void_p), ("stage", C.c_int), ("args", _List), ("rets", _List), ("attrs", _Attrs),
                ("future", C.c_void_p)]


class _ErrorCreateArgs(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p), ("message", C.c_char_p),
                ("errc", C.c_int)]


class _Api(C.Structure):  # the head of XLA_FFI_Api: what is needed to create an error
    _fields_ = [("struct_size", C.c_size_t), ("extension_start", C.c_void_p), ("api_version", _ApiVersion),
                ("internal_api", C.c_void_p), ("error_create", C.c_void_p)]


_HANDLER = C.CFUNCTYPE(C.c_void_p, C.POINTER(_CallFrame))
_ERROR_CREATE = C.CFUNCTYPE(C.c_void_p, C.POINTER(_ErrorCreateArgs))

#: What a handler calls: a function of (kind, x (rows, size_in), out (rows, size_out)) filling out.
_DISPATCH = None
_LOCK = threading.Lock()
_REGISTERED: dict = {}


#: NumPy views of XLA's buffers by (address, shape): a compiled loop hands the custom call the same
#: buffers at every step, so the views are made once (bounded: cleared past 4,096 entries).
_VIEWS: dict = {}


def _buffer(ptr) -> np.ndarray:
    b = _Buffer.from_address(ptr)
    if b.dtype != _F64:
        raise TypeError(f"float64 buffers expected, got XLA dtype {b.dtype}")
    dims = b.dims
    shape = tuple(dims[i] for i in range(b.rank))
    key = (b.data, shape)
    view = _VIEWS.get(key)
    if view is None:
        n = int(np.prod(shape)) if shape else 1
        view = np.ctypeslib.as_array((C.c_double * n).from_address(b.data)).reshape(shape)
        if len(_VIEWS) > 4096:
            _VIEWS.clear()
        _VIEWS[key] = view
    return view


def _error(frame, message: str):
    api = C.cast(frame.api, C.POINTER(_Api)).contents
    create = _ERROR_CREATE(api.error_create)
    text = C.create_string_buffer(message.encode()[:2000])
    args = _ErrorCreateArgs(C.sizeof(_ErrorCreateArgs), None, C.cast(text, C.c_char_p), _INTERNAL)
    return create(C.byref(args))


def _make_handler(kind: str):
    def handler(frame_ptr):
        frame = frame_ptr.contents
        ext = frame.extension_start
        if ext and ext.contents.type == _METADATA:  # XLA asks which FFI API version the handler speaks
            md = C.cast(ext, C.POINTER(_MetadataExtension)).contents.metadata.contents
            md.api_version.major_version, md.api_version.minor_version = 0, 3
            md.traits = 0
            return None
        if frame.stage != _EXECUTE:
            return None
        try:
            x = _buffer(frame.args.items[0])
            out = _buffer(frame.rets.items[0])
            del ext
            _DISPATCH(kind, x, out)
            return None
        except BaseException as err:  # noqa: BLE001 - reported to XLA as the call's error
            return _error(frame, f"hinfnn MuJoCo {kind}: {type(err).__name__}: {err}\n{traceback.format_exc()[-1500:]}")

    return _HANDLER(handler)


def register(dispatch) -> None:
    """Register the two FFI targets (once per process); ``dispatch(kind, x, out)`` does the work."""
    global _DISPATCH
    with _LOCK:
        _DISPATCH = dispatch
        for kind, name in TARGETS.items():
            if kind in _REGISTERED:
                continue
            fn = _make_handler(kind)
            jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(fn), platform="cpu")
            _REGISTERED[kind] = fn  # keep the ctypes function alive for the process's lifetime


def call(kind: str, x, size_out: int):
    """The traced call: rows x (..., size_in) -> (..., size_out), float64; batched by broadcasting
    every batch axis into the leading dimensions (one call for a whole vmap batch)."""
    out = jax.ShapeDtypeStruct(x.shape[:-1] + (size_out,), np.float64)
    return jax.ffi.ffi_call(TARGETS[kind], out, vmap_method="broadcast_all")(x)
