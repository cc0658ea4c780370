"""Where the compiled (numba) kernels are cached, and loading them: run explicitly, never on import.

Pure Python, no ROS. The kernel modules (``biped_model.planar_kernels``,
``biped_sim.plant.mujoco_kernels``, ``biped_controller.core.qp.exact_kernels``, ``biped_controller.core.control.controller_kernels``,
``biped_controller.core.control.wbc_kernels``, ``biped_controller.core.sensing.pipeline_kernels``,
``biped_controller.core.sensing.model_error_kernels``, ``biped_controller.closed_loop.loop_kernels``,
``biped_controller.closed_loop.mujoco_loop_kernels``) only define kernels; they are imported through :func:`load`,
which

1. points numba's on-disk cache at ``<repo>/build/numba-cache`` (``NUMBA_CACHE_DIR`` when set), before the
   module's kernels are decorated (numba picks a function's cache location when it is decorated);
2. drops the module's cached files when a module it was compiled against changed (``sources``): numba
   keys a module's cache on that module's own source only, so a kernel inlining another module's
   kernels or layout offsets would otherwise keep their old machine code;
3. says on ``stream`` (stderr) that it compiles when the module's stamp does not match its source,
   numba and Python versions (the first run after a change, ~15-60 s), then imports the module and
   records the stamp.

A kernel module imported any other way raises :class:`CacheNotConfigured` (``require_configured``), so a
kernel never lands in a stray cache. ``scripts/setup`` compiles every kernel once (``compile step``).
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.util
import os
import sys
import time
from importlib.metadata import version as _dist_version
from pathlib import Path
from types import ModuleType
from typing import Sequence, TextIO

from biped_model.settings import repo_root

COMPILE_NOTICE = "fast engine: compiling numba kernels (first run, ~15 s)..."


class CacheNotConfigured(RuntimeError):
    """A kernel module was imported before :func:`configure` (import it with :func:`load`)."""


def cache_dir() -> Path:
    """``NUMBA_CACHE_DIR`` when set, else ``<repo>/build/numba-cache`` (the repository's ignored build area)."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    return Path(env) if env else repo_root() / "build" / "numba-cache"


def configure() -> Path:
    """Point numba's cache at :func:`cache_dir` for the kernels decorated from now on (numba's own config,
    no environment variable); returns the directory."""
    import numba

    root = cache_dir()
    numba.config.CACHE_DIR = str(root)
    return root


def require_configured(module: str) -> None:
    """Called at the top of a kernel module: raises :class:`CacheNotConfigured` unless :func:`configure` ran
    (the kernels would otherwise be cached beside the sources, without the dependency check)."""
    import numba

    if numba.config.CACHE_DIR != str(cache_dir()):
        raise CacheNotConfigured(f"{module} is a numba kernel module: import it with "
                                 f"biped_model.numba_cache.load({module!r}, ...)")


def cache_key(source: Path) -> str:
    """What numba's on-disk cache of this module depends on: the source (content, mtime and size, which
    numba's index checks), the numba version and the Python version."""
    st = source.stat()
    h = hashlib.sha256(source.read_bytes())
    h.update(f"|{st.st_mtime!r}|{st.st_size}|numba {_dist_version('numba')}|{sys.version}".encode())
    return h.hexdigest()


def announce_compile(stamp: Path, key: str, stream: TextIO) -> bool:
    """Print COMPILE_NOTICE on ``stream`` unless ``stamp`` records ``key`` (the cache is then warm).
    Returns True when it printed."""
    try:
        if stamp.read_text(encoding="utf-8").strip() == key:
            return False
    except OSError:
        pass
    print(COMPILE_NOTICE, file=stream, flush=True)
    return True


def write_stamp(stamp: Path, key: str) -> None:
    """Record ``key`` in ``stamp`` (atomic replace; a read-only build area is not an error)."""
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        tmp = stamp.with_name(f"{stamp.name}.{os.getpid()}.tmp")
        tmp.write_text(key + "\n", encoding="utf-8")
        os.replace(tmp, stamp)
    except OSError:
        pass


def drop_stale_cache(module: str, sources: list[Path], cache_dir: str | Path) -> bool:
    """Delete the cached files of ``module`` (``<module>.*.nbi/.nbc`` under ``cache_dir``) when the
    ``sources`` it was compiled against (its own included) changed since the last call; returns True when
    it deleted. Call it before the module is imported."""
    root = Path(cache_dir)
    h = hashlib.sha256()
    for src in sources:
        h.update(src.read_bytes())
    key = h.hexdigest()
    stamp = root / f"{module}.deps"
    try:
        if stamp.read_text(encoding="utf-8").strip() == key:
            return False
    except OSError:
        pass
    dropped = False
    if root.is_dir():
        for f in list(root.rglob(f"{module}.*.nb[ic]")):
            try:
                f.unlink()
                dropped = True
            except OSError:
                pass
    write_stamp(stamp, key)
    return dropped


def source_of(module: str) -> Path:
    """The source file of ``module`` without importing it."""
    spec = importlib.util.find_spec(module)
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(f"no source for {module!r}", name=module)
    return Path(spec.origin)


def load(module: str, sources: Sequence[str] = (), stream: TextIO | None = None) -> ModuleType:
    """Import the kernel module ``module`` with its cache kept right (module docstring): ``sources`` are the
    modules its compiled code depends on besides its own source (kernels it calls, layouts it reads).
    A module already imported is returned as it is."""
    loaded = sys.modules.get(module)
    if loaded is not None:
        return loaded
    root = configure()
    own = source_of(module)
    short = module.rsplit(".", 1)[-1]
    dropped = bool(sources) and drop_stale_cache(short, [source_of(s) for s in sources] + [own], root)
    stamp = root / f"{short}.stamp"
    key = cache_key(own)
    out = stream if stream is not None else sys.stderr
    if dropped:
        stamp.unlink(missing_ok=True)     # compiled afresh: say so
    compiling = announce_compile(stamp, key, out)
    t0 = time.perf_counter()
    mod = importlib.import_module(module)
    if compiling:
        print(f"fast engine: {module} compiled in {time.perf_counter() - t0:.1f} s", file=out, flush=True)
    write_stamp(stamp, key)
    return mod
