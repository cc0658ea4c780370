"""The thread count of the OpenBLAS libraries loaded in this process (NumPy's and SciPy's own copies).

Why it matters for the gait family: scipy's SLSQP solves its least-squares subproblem (about 960
constraint rows by 30 unknowns here) through OpenBLAS, and the result of a multi-threaded OpenBLAS
call is not bit for bit the one of a single-threaded call (the work is split, the partial sums are
added in another order). One SLSQP solve of the preferred stride differs after 40 iterations by
2.5e-3 in the criterion between 1 and 2 threads, and the generation chains hundreds of warm-started
solves, so the family depends on the number of cores of the machine (and on ``OPENBLAS_NUM_THREADS``).
On a loaded machine two OpenBLAS threads are also much slower than one (they wait for each other).

:func:`set_blas_threads` sets every loaded OpenBLAS to ``n`` threads (through its own
``*_set_num_threads`` entry point, found with ctypes; no extra package) and ``OPENBLAS_NUM_THREADS``
for child processes; :func:`blas_info` says what is loaded (library, kernel core type, threads).
"""
from __future__ import annotations

import ctypes
import os

_SET = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
        "openblas_set_num_threads")
_GET = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads64_",
        "openblas_get_num_threads")
_CORE = ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename64_",
         "openblas_get_corename")


def _loaded_openblas() -> list[str]:
    """Paths of the OpenBLAS shared libraries mapped into this process (Linux: /proc/self/maps)."""
    import numpy  # noqa: F401  (load NumPy's copy)
    import scipy.linalg  # noqa: F401  (load SciPy's copy)
    out: list[str] = []
    try:
        with open("/proc/self/maps", encoding="utf-8") as f:
            for line in f:
                parts = line.split()
                if len(parts) >= 6 and "openblas" in parts[-1].lower() and parts[-1] not in out:
                    out.append(parts[-1])
    except OSError:
        pass
    return sorted(out)


def _symbol(lib: ctypes.CDLL, names: tuple[str, ...]):
    for n in names:
        fn = getattr(lib, n, None)
        if fn is not None:
            return fn
    return None


def set_blas_threads(n: int = 1) -> list[str]:
    """Set every loaded OpenBLAS to ``n`` threads (and ``OPENBLAS_NUM_THREADS`` for children). Returns
    the libraries set."""
    os.environ["OPENBLAS_NUM_THREADS"] = str(int(n))
    done = []
    for path in _loaded_openblas():
        lib = ctypes.CDLL(path)
        fn = _symbol(lib, _SET)
        if fn is not None:
            fn.argtypes = [ctypes.c_int]
            fn.restype = None
            fn(int(n))
            done.append(path)
    return done


def blas_info() -> list[dict]:
    """Each loaded OpenBLAS: file name, kernel core type (OpenBLAS picks it from the CPU at load time), threads."""
    out = []
    for path in _loaded_openblas():
        lib = ctypes.CDLL(path)
        get, core = _symbol(lib, _GET), _symbol(lib, _CORE)
        rec = {"library": os.path.basename(path)}
        if get is not None:
            get.restype = ctypes.c_int
            rec["threads"] = int(get())
        if core is not None:
            core.restype = ctypes.c_char_p
            rec["core"] = (core() or b"").decode()
        out.append(rec)
    return out
