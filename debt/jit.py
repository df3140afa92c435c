# How DEBT compiles its hot loops: numba's njit, cached on disk when the package
# folder is writable, without reference counting where the kernel allocates
# nothing.  Without numba the same functions run as plain Python (slowly).

from __future__ import annotations

import os

try:  # numba is a dependency, but the pure-Python path keeps things working.
    import numba as _numba
except ImportError:  # pragma: no cover - exercised only without numba
    _numba = None


def _cache_dir() -> str:
    return os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.path.dirname(os.path.abspath(__file__)), "__pycache__")


def _cache_ok() -> bool:
    # numba's on-disk cache needs a writable __pycache__ beside this file (or
    # NUMBA_CACHE_DIR); without one it raises, so compile each process instead.
    here = _cache_dir()
    try:
        os.makedirs(here, exist_ok=True)
        ok = os.access(here, os.W_OK)
    except OSError:
        return False
    if ok:
        _drop_stale_cache(here)
    return ok


def _drop_stale_cache(here: str) -> None:
    # numba keys a cached function by its own file only, but the traversal
    # inlines the range coder (rangecoder.py) and the kernels freeze constants
    # of transform.py: a change there would leave stale machine code behind.
    # So the cache of this package goes whenever any of its sources changes.
    import hashlib

    folder = os.path.dirname(os.path.abspath(__file__))
    digest = hashlib.sha256()
    for name in sorted(os.listdir(folder)):
        if name.endswith(".py"):
            with open(os.path.join(folder, name), "rb") as f:
                digest.update(name.encode() + b"\0" + f.read())
    stamp = os.path.join(here, "debt-sources.sha256")
    try:
        with open(stamp) as f:
            if f.read() == digest.hexdigest():
                return
    except OSError:
        pass
    try:
        modules = {n[:-3] for n in os.listdir(folder) if n.endswith(".py")}
        for name in os.listdir(here):
            if name.endswith((".nbi", ".nbc")) and name.split(".", 1)[0] in modules:
                os.remove(os.path.join(here, name))
        tmp = f"{stamp}.{os.getpid()}"
        with open(tmp, "w") as f:
            f.write(digest.hexdigest())
        os.replace(tmp, stamp)
    except OSError:  # another process got there first, or a read-only cache
        pass


# A warm-up that ran to its end with the cache as it is marks it so (the sources'
# stamp copied): `rovlink demo` then knows it only loads, however long loading takes
# on a loaded machine, rather than guessing from the time it takes.
_WARMED = "debt-warm-up.sha256"


def _stamp(name: str) -> str | None:
    try:
        with open(os.path.join(_cache_dir(), name)) as f:
            return f.read()
    except OSError:
        return None


def warmed() -> bool:
    """Whether every kernel was compiled into the on-disk cache for these sources."""
    stamp = _stamp("debt-sources.sha256")
    return stamp is not None and _stamp(_WARMED) == stamp


def mark_warmed() -> None:
    stamp = _stamp("debt-sources.sha256")
    if stamp is None:
        return  # no cache on disk: every process compiles anew
    path = os.path.join(_cache_dir(), _WARMED)
    try:
        tmp = f"{path}.{os.getpid()}"
        with open(tmp, "w") as f:
            f.write(stamp)
        os.replace(tmp, path)
    except OSError:  # a read-only cache
        pass


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
    # stays in registers), and so are the coder's context helpers: called,
    # each took a dozen arrays as arguments on the stack (the traversal of a
    # camera picture at 4000 B: 1.7 -> 1.37 ms; the first compilation of the
    # package ~25 -> ~28 s).
    _inline = _numba.njit(cache=_cache_ok(), nogil=True, inline="always", **_NO_NRT)
else:  # pragma: no cover
    def _jit(f):
        return f
    _inline = _jit_nrt = _jit
