"""Restricted loading of pickles and ``.npz`` files: data only, never code.

GRAB stores dict-valued keys as 0-d object arrays (pickled), and the official
MANO / SMPL-X ``.pkl`` files hold ``chumpy`` arrays and scipy sparse matrices.
Plain ``pickle`` would execute whatever a file names. The unpickler here
resolves only a short allow-list of classes (numpy arrays, dtypes and scalars,
builtin containers and numbers) and refuses everything else *before* calling
it, so nothing in a hostile file runs.

Optional extras for licensed model files:
- ``allow_chumpy=True`` maps ``chumpy.ch.Ch`` to a shell that keeps only the
  wrapped array (chumpy itself is never imported);
- ``allow_sparse=True`` admits scipy's csc/csr/coo matrices (the MANO joint
  regressor), which are rebuilt from their arrays.

Python 2 names (``copy_reg``, ``__builtin__``) are mapped to Python 3 before the
allow-list check, and ``_codecs.encode`` (how Python 3 protocol-2 pickles store bytes)
is replaced by a latin1-only encoder.
"""

from __future__ import annotations

import _compat_pickle
import io
import os
import pickle
import zipfile
from typing import IO, Any

import numpy as np

from .constants import NPZ_MAX_MEMBER_BYTES
from .errors import GripBenchError, InputError, UnsafeFileError

_NUMPY_CORE = ("numpy.core.multiarray", "numpy._core.multiarray")
_ALLOWED: set[tuple[str, str]] = {
    *((m, "_reconstruct") for m in _NUMPY_CORE),
    *((m, "scalar") for m in _NUMPY_CORE),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("builtins", "dict"),
    ("builtins", "list"),
    ("builtins", "tuple"),
    ("builtins", "set"),
    ("builtins", "frozenset"),
    ("builtins", "str"),
    ("builtins", "bytes"),
    ("builtins", "int"),
    ("builtins", "float"),
    ("builtins", "complex"),
    ("builtins", "bool"),
    ("collections", "OrderedDict"),
    # protocol-5 pickles of contiguous arrays (np.frombuffer + reshape)
    ("numpy.core.numeric", "_frombuffer"),
    ("numpy._core.numeric", "_frombuffer"),
    ("builtins", "bytearray"),
}
# numpy dtype classes pickled by numpy>=1.25 (numpy.dtypes.Float64DType, ...). Only the
# DType classes themselves: the module also holds helpers and dunders (``__loader__``)
# that a dotted protocol-4 name could reach.
_DTYPE_MODULES = ("numpy.dtypes",)

_SPARSE = {
    ("scipy.sparse.csc", "csc_matrix"),
    ("scipy.sparse._csc", "csc_matrix"),
    ("scipy.sparse.csr", "csr_matrix"),
    ("scipy.sparse._csr", "csr_matrix"),
    ("scipy.sparse.coo", "coo_matrix"),
    ("scipy.sparse._coo", "coo_matrix"),
}


class ChumpyArray:
    """Stand-in for ``chumpy.ch.Ch``: keeps the wrapped value ``x`` only."""

    def __setstate__(self, state: Any) -> None:
        if isinstance(state, tuple) and state and isinstance(state[0], dict):
            state = state[0]  # (dict state, slot state)
        self.x = state.get("x") if isinstance(state, dict) else None

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        return np.asarray(self.x, dtype=dtype)


class _SparseShell:
    """Collects a scipy sparse matrix's pickled state without importing scipy code paths."""

    def __init__(self, kind: str):
        self.kind = kind
        self.state: dict = {}

    def __setstate__(self, state: Any) -> None:
        self.state = dict(state) if isinstance(state, dict) else {}

    def toarray(self) -> np.ndarray:
        import scipy.sparse as sp

        s = self.state
        shape = tuple(s.get("_shape", s.get("shape")))
        if self.kind == "coo_matrix":
            return sp.coo_matrix((s["data"], (s["row"], s["col"])), shape=shape).toarray()
        cls = sp.csc_matrix if self.kind == "csc_matrix" else sp.csr_matrix
        return cls((s["data"], s["indices"], s["indptr"]), shape=shape).toarray()


def _reconstructor(cls: Any, base: Any, state: Any) -> Any:
    """Safe replacement of ``copyreg._reconstructor`` for our shell classes only."""
    obj = cls.__new__(cls) if not callable(cls) or isinstance(cls, type) else cls()
    return obj


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that resolves only plain-data classes (see module docstring)."""

    def __init__(self, file: IO[bytes], *, allow_chumpy: bool = False, allow_sparse: bool = False,
                 source: str = "<stream>"):
        super().__init__(file, encoding="latin1")
        self.allow_chumpy = allow_chumpy
        self.allow_sparse = allow_sparse
        self.source = source

    def find_class(self, module: str, name: str) -> Any:
        module, name = _py3_name(module, name)
        if (module, name) in _ALLOWED or (module in _DTYPE_MODULES and _is_dtype_name(name)):
            return super().find_class(module, name)
        if (module, name) == ("_codecs", "encode"):
            return _latin1_bytes
        if self.allow_chumpy and module.startswith("chumpy"):
            return ChumpyArray
        if self.allow_sparse and (module, name) in _SPARSE:
            return _make_sparse_factory(name)
        if (self.allow_chumpy or self.allow_sparse) and (module, name) == (
            "copyreg",
            "_reconstructor",
        ):
            return _reconstructor
        if (self.allow_chumpy or self.allow_sparse) and (module, name) == ("builtins", "object"):
            return object
        raise UnsafeFileError(
            f"refused to unpickle '{module}.{name}': only numpy arrays and plain data are accepted",
            self.source,
        )


def _py3_name(module: str, name: str) -> tuple[str, str]:
    """Python 2 names (``copy_reg``, ``__builtin__``; the official model files are
    Python 2 pickles) mapped to Python 3, as the default ``find_class`` would."""
    if (module, name) in _compat_pickle.NAME_MAPPING:
        return _compat_pickle.NAME_MAPPING[(module, name)]
    return _compat_pickle.IMPORT_MAPPING.get(module, module), name


def _latin1_bytes(text: str, encoding: str = "latin1") -> bytes:
    """``_codecs.encode`` as Python 3 protocol-2 pickles use it for ``bytes`` (latin1 only)."""
    if not isinstance(text, str) or encoding.replace("-", "").lower() != "latin1":
        raise pickle.UnpicklingError(f"refused _codecs.encode with encoding {encoding!r}")
    return text.encode("latin1")


def _is_dtype_name(name: str) -> bool:
    """A plain ``numpy.dtypes`` DType class name (no dots, no dunders)."""
    return name.isidentifier() and name.endswith("DType") and not name.startswith("_")


def _make_sparse_factory(kind: str) -> type[_SparseShell]:
    class _Sparse(_SparseShell):
        def __init__(self, *args: Any, **kwargs: Any):
            super().__init__(kind)

        def __new__(cls, *args: Any, **kwargs: Any) -> _SparseShell:
            obj = object.__new__(cls)
            obj.kind = kind
            obj.state = {}
            return obj

    _Sparse.__name__ = kind
    return _Sparse


def load_pickle(path: str | os.PathLike, *, allow_chumpy: bool = False,
                allow_sparse: bool = False) -> Any:
    """Load a pickle file with the restricted unpickler; chumpy/sparse values become ndarrays."""
    try:
        with open(path, "rb") as f:
            obj = RestrictedUnpickler(f, allow_chumpy=allow_chumpy, allow_sparse=allow_sparse,
                                      source=str(path)).load()
        return _to_plain(obj)
    except GripBenchError:
        raise
    except OSError as e:
        raise InputError(f"cannot read ({e.strerror or e})", path) from e
    except Exception as e:  # noqa: BLE001 - any parse failure of untrusted bytes is bad input
        raise InputError(f"not a readable pickle ({type(e).__name__}: {_one_line(e)})",
                         path) from e


def _one_line(e: BaseException) -> str:
    """An exception's message on one line (the CLI's errors are one line each)."""
    return " ".join(str(e).split())[:300]


def _to_plain(obj: Any) -> Any:
    """Replace chumpy and sparse shells by ndarrays, recursively through containers."""
    if isinstance(obj, ChumpyArray):
        if obj.x is None:
            raise ValueError("a chumpy object without a stored value 'x'")
        return np.asarray(_to_plain(obj.x))
    if isinstance(obj, _SparseShell):
        return obj.toarray()
    if isinstance(obj, dict):
        return {k: _to_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(_to_plain(v) for v in obj)
    return obj


def _read_npy(raw: bytes, source: str) -> np.ndarray:
    """Read one ``.npy`` member; object arrays go through the restricted unpickler."""
    f = io.BytesIO(raw)
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
    else:  # (3, 0): utf8 header, same layout as 2.0
        shape, fortran, dtype = np.lib.format._read_array_header(f, version)
    if dtype.hasobject:
        arr = RestrictedUnpickler(f, source=source).load()
        return _to_plain(arr) if not isinstance(arr, np.ndarray) else arr
    declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if declared > len(raw) - f.tell():
        # numpy would allocate the declared size before finding the data short
        raise InputError(f"header declares shape {shape} of {dtype} ({declared} bytes) but the "
                         f"member holds {len(raw) - f.tell()} bytes of data", source)
    f.seek(0)
    return np.lib.format.read_array(f, allow_pickle=False)


def load_npz(path: str | os.PathLike) -> dict[str, Any]:
    """Load every array of an ``.npz`` safely. 0-d object arrays are unwrapped with ``.item()``.

    Raises :class:`InputError` naming the file (and key) for a truncated or
    corrupt archive, and :class:`UnsafeFileError` for pickled code.
    """
    out: dict[str, Any] = {}
    try:
        zf = zipfile.ZipFile(path)
    except OSError as e:
        raise InputError(f"cannot read ({e.strerror or e})", path) from e
    except Exception as e:  # noqa: BLE001 - BadZipFile, or worse from crafted bytes
        raise InputError(f"not a readable .npz archive ({_one_line(e)})", path) from e
    with zf:
        for info in zf.infolist():
            member = info.filename
            key = member[:-4] if member.endswith(".npy") else member
            if info.file_size > NPZ_MAX_MEMBER_BYTES:
                raise InputError(f"member unpacks to {info.file_size} bytes (more than "
                                 f"{NPZ_MAX_MEMBER_BYTES}): refused", f"{path}: {key}")
            try:
                arr = _read_npy(zf.read(info), f"{path}: {key}")
            except GripBenchError:
                raise
            except Exception as e:  # noqa: BLE001 - any parse failure of untrusted bytes
                raise InputError(
                    f"corrupt array ({type(e).__name__}: {_one_line(e)})", f"{path}: {key}"
                ) from e
            if isinstance(arr, np.ndarray) and arr.dtype.hasobject and arr.shape == ():
                arr = arr.item()
            out[key] = arr
    return out
