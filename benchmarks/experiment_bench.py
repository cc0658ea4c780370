"""Section 5 of ``scripts/bench``: wall time of the four-mode max-push table
(biped_controller.studies.trial.search.max_push_modes), serial and over a process pool of os.cpu_count()
workers, same settings, side by side in one run."""
from __future__ import annotations

import importlib.util
import os
import time


def time_table(quick: bool) -> dict:
    from biped_controller.studies.trial import search as ex
    from biped_controller.core.control.config import MODES

    if quick:
        kw = dict(resolution=25.0, fmax=100.0, coarse=50.0)
    else:
        kw = dict(resolution=5.0, fmax=2000.0, coarse=50.0)   # the experiment's defaults
    workers = max(2, os.cpu_count() or 2)
    out = {"available": True, "settings": kw, "workers": workers, "modes": list(MODES)}
    t0 = time.perf_counter()
    par = ex.max_push_modes(tuple(MODES), workers=workers, progress=False, **kw)
    out["parallel_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ser = ex.max_push_modes(tuple(MODES), workers=1, progress=False, **kw)
    out["serial_s"] = time.perf_counter() - t0
    out["speedup"] = out["serial_s"] / out["parallel_s"]

    def edge(r):
        return {k: r.get(k) for k in ("max_force", "first_failure", "islands") if k in r}
    out["max_push"] = {m: edge(r) for m, r in ser.items()}
    out["serial_equals_parallel"] = all(edge(ser[m]) == edge(par[m]) for m in ser)
    return out


def bench_experiment(quick: bool) -> dict:
    if importlib.util.find_spec("biped_controller.studies.experiment") is None:
        return {"available": False, "reason": "not available: biped_controller.studies.experiment not written yet"}
    if quick:   # the table takes minutes even with coarse settings: only check the API is there
        import inspect
        from biped_controller.studies.trial import search
        sig = inspect.signature(search.max_push_modes)
        missing = [k for k in ("resolution", "fmax", "coarse", "workers", "progress") if k not in sig.parameters]
        return {"available": False, "reason": "skipped in --quick" + (f" (API changed: {missing})" if missing else "")}
    try:
        return time_table(quick)
    except Exception as exc:  # noqa: BLE001
        return {"available": False, "reason": f"not available: {type(exc).__name__}: {exc}"}
