"""Benchmarks (code only): each writes its figures under :data:`RESULTS_DIR` with a provenance record
(``biped_controller.studies.provenance``; layout in ``results/README.md``)."""
from pathlib import Path

RESULTS_DIR = Path(__file__).resolve().parents[1] / "results" / "benchmarks"
