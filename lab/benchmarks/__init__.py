"""One-off benchmark investigations (code only; ``scripts/bench`` runs none of them): each answered one
question about a cost, with its figures under ``results/`` (``lab/README.md``). Run from the repository
root: ``.venv/bin/python -m lab.benchmarks.NAME``."""
