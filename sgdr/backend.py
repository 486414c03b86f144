"""The one place that chooses the Dr.Jit / Mitsuba backend.

Entry points (experiments, tests, benchmarks) call `init(...)` once; library modules ask for
array types at call time through `ad()` (the Dr.Jit AD namespace, e.g. `drjit.llvm.ad`) and
never choose a variant at import.

- `llvm` -> Mitsuba variant `llvm_ad_rgb`, Dr.Jit `drjit.llvm.ad` (the default; CPU).
- `cuda` -> Mitsuba variant `cuda_ad_rgb`, Dr.Jit `drjit.cuda.ad` (when asked and present).

Dr.Jit's LLVM backend loads libLLVM at run time. Debian bookworm ships 14/15, with which
`dr.maximum` aborts ("Cannot select fmaximum"); we need >= 16 and point `DRJIT_LIBLLVM_PATH` at
the newest libLLVM found, unless the user has set it.
"""

from __future__ import annotations

import glob
import logging
import os
import re
from dataclasses import dataclass

from sgdr.registry import Registry

log = logging.getLogger(__name__)

MIN_LLVM = 16
_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
    "/usr/local/opt/llvm/lib/libLLVM.dylib",
)


class BackendError(RuntimeError):
    """The requested backend cannot be used; the message says what to install or change."""


# backend name -> Mitsuba variant
_VARIANTS = Registry("backend", "backend", BackendError, {"llvm": "llvm_ad_rgb", "cuda": "cuda_ad_rgb"})


@dataclass(frozen=True)
class Backend:
    name: str  # "llvm" | "cuda"
    variant: str  # Mitsuba variant, e.g. "llvm_ad_rgb"
    threads: int  # Dr.Jit thread-pool size (LLVM backend)


_current: Backend | None = None


def _llvm_version(path: str) -> int:
    m = re.search(r"LLVM-?(\d+)", os.path.basename(path))
    if m:
        return int(m.group(1))
    m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else 0


def find_libllvm() -> str | None:
    """Path of the newest libLLVM on this machine (None if there is none)."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        return env
    found = sorted({p for g in _LLVM_GLOBS for p in glob.glob(g)}, key=_llvm_version)
    return found[-1] if found else None


def check_llvm() -> str:
    """Make sure a usable libLLVM (>= 16) is found and exported; return its path."""
    path = find_libllvm()
    if path is None:
        raise BackendError(
            "Dr.Jit's LLVM backend needs libLLVM >= 16 and none was found. "
            "On Debian: `apt-get install libllvm19` (or run `make setup`), "
            "or set DRJIT_LIBLLVM_PATH to a libLLVM shared library."
        )
    version = _llvm_version(path)
    if "DRJIT_LIBLLVM_PATH" not in os.environ and version < MIN_LLVM:
        raise BackendError(
            f"Newest libLLVM found is {path} (version {version}); Dr.Jit needs >= {MIN_LLVM} "
            "(with 14/15 `dr.maximum` aborts). On Debian: `apt-get install libllvm19`."
        )
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", path)
    return path


def cuda_available() -> bool:
    """True when Dr.Jit can start its CUDA backend on this machine."""
    import drjit as dr

    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # noqa: BLE001 - a missing driver raises various errors
        return False


# Every `dr.freeze`-recorded function sgdr makes (`frozen`): their recordings are dropped when the
# thread count changes, so none replays kernels recorded for another thread pool (the LLVM
# backend's scatter-reductions size per-thread buffers at record time).
_FROZEN: list = []


def frozen(fn, **kwargs):
    """`dr.freeze(fn, **kwargs)`, registered so that `init` clears its recordings whenever the
    thread count changes."""
    import drjit as dr

    f = dr.freeze(fn, **kwargs)
    _FROZEN.append(f)
    return f


def init(name: str = "llvm", threads: int | None = None) -> Backend:
    """Choose the backend once per process. Repeating the same choice is a no-op.

    name: "llvm" (CPU, default) or "cuda" (GPU; must be present).
    threads: Dr.Jit thread-pool size for the LLVM backend (None: all cores). This is how
      the pool is sized; the DRJIT_NUM_THREADS variable is ignored by Dr.Jit.
    """
    global _current
    variant = _VARIANTS.get_named(name)
    if _current is not None:
        if _current.name != name:
            raise BackendError(f"backend already initialised as {_current.name!r}; one process uses one backend")
        if threads is not None and threads != _current.threads:
            import drjit as dr

            dr.set_thread_count(threads)
            for f in _FROZEN:
                f.clear()
            _current = Backend(name, _current.variant, threads)
        return _current
    if name == "llvm":
        check_llvm()
    import drjit as dr
    import mitsuba as mi

    if name == "cuda" and not cuda_available():
        raise BackendError("backend 'cuda' was asked for but Dr.Jit finds no CUDA device/driver")
    if variant not in mi.variants():
        raise BackendError(f"Mitsuba build lacks variant {variant!r}; has {mi.variants()}")
    mi.set_variant(variant)
    n = int(threads) if threads else (os.cpu_count() or 1)
    if name == "llvm":
        dr.set_thread_count(n)
    _current = Backend(name, variant, n)
    log.info("sgdr backend: %s (%s), %d threads", name, variant, n)
    return _current


def current() -> Backend:
    """The active backend; initialises the default (LLVM) on first use."""
    return _current if _current is not None else init()


def ad():
    """Dr.Jit AD array namespace of the active backend (`drjit.llvm.ad` or `drjit.cuda.ad`)."""
    import drjit as dr

    b = current()
    return dr.cuda.ad if b.name == "cuda" else dr.llvm.ad
