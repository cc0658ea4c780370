"""The laboratory: investigations that answered one question once, kept so their answers can be re-run.

Not installed and not part of the product: nothing under ``src/`` and no file of ``tests/`` imports it
(``tests/test_layout.py``). Run from the repository root (the working directory is on ``sys.path`` with
``python -m``), e.g. ``.venv/bin/python -m lab.sweep_check compare A B``; its tests are ``lab/tests``, run by
``scripts/test`` with ``tests``. The index, each investigation's question, answer, commands and files, is
``lab/README.md``.
"""
