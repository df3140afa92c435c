# How DEBT compiles its hot loops: numba's njit, cached on disk when the package
# folder is writable, without reference counting where the kernel allocates
# nothing.  Without numba the same functions run as plain Python (slowly).

from __future__ import annotations

import os

try:  # numba is a dependency, but the pure-Python path keeps things working.
    import numba as _numba
except ImportError:  # pragma: no cover - exercised only without numba
    _numba = None


def _cache_ok() -> bool:
    # numba's on-disk cache needs a writable __pycache__ beside this file (or
    # NUMBA_CACHE_DIR); without one it raises, so compile each process instead.
    if os.environ.get("NUMBA_CACHE_DIR"):
        return True
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "__pycache__")
    try:
        os.makedirs(here, exist_ok=True)
        return os.access(here, os.W_OK)
    except OSError:
        return False


if _numba is not None:
    # No reference counting (_nrt=False): profiling showed two thirds of the
    # traversal's time in the atomic increments numba wraps around every
    # array passed to a helper.  The kernels therefore allocate nothing; the
    # Python wrappers hand them their work arrays.
    # `_nrt` is a private numba option: when a numba no longer has it the
    # kernels compile with reference counting (slower, the same streams).
    def _nrt_option_known() -> bool:
        try:
            from numba.core.cpu import CPUTargetOptions
        except ImportError:  # pragma: no cover - a numba laid out otherwise
            return False
        return hasattr(CPUTargetOptions, "_nrt")

    _NO_NRT = {"_nrt": False} if _nrt_option_known() else {}
    _jit = _numba.njit(cache=_cache_ok(), nogil=True, **_NO_NRT)
    _jit_nrt = _numba.njit(cache=_cache_ok(), nogil=True)  # for kernels that allocate
    # The binary coder is inlined by numba itself (its scalar state then
    # stays in registers); other helpers are left to LLVM, since inlining
    # them all tripled the first compilation for ~15 % speed.
    _inline = _numba.njit(cache=_cache_ok(), nogil=True, inline="always", **_NO_NRT)
else:  # pragma: no cover
    def _jit(f):
        return f
    _inline = _jit_nrt = _jit
