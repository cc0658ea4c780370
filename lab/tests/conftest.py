"""lab/tests: the suite's own directory ``tests/`` on ``sys.path`` (its helpers and the synthetic survival
functions of ``test_capability_map``), as pytest puts it there when it collects ``tests/``; so these tests
also run alone (``pytest lab/tests``). The repository root, for ``import lab``, is put on ``sys.path`` by
pytest itself (``lab/`` and ``lab/tests/`` are packages)."""
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parents[2] / "tests"
if str(TESTS) not in sys.path:
    sys.path.insert(0, str(TESTS))
