"""Wall time of the four-mode max-push table (biped_controller.studies.trial.search.max_push_modes), serial
and over a process pool of os.cpu_count() workers, same settings, side by side in one run."""
from __future__ import annotations

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
