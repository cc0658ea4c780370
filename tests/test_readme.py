"""Every shell command that README.md shows is checked, so the README cannot drift from the code.

The commands are the lines of the README's ```` ```bash ```` blocks (a trailing ``# comment`` dropped,
``\\`` continuations joined). Each is checked the cheapest way that still exercises its whole command
line:

* ``scripts/demo`` and ``scripts/test`` on their own (the two top-level commands, minutes each): the
  script exists and is executable; they are not run.
* ``scripts/run_node PKG EXE ...``: the executable resolves through the ament index of ``.venv`` exactly
  as the script resolves it (``biped_sim.graph.launch.find_executable``), and every repository file
  the line names (``--params-file config/graph.yaml``) exists.
* every other line (``scripts/X ...`` or ``.venv/bin/python -m MODULE ...``): the script exists and is
  executable (or the module imports), and the whole line with ``--help`` appended exits 0. argparse
  handles the options in order, so a bad subcommand, a bad choice (``--observer maybe``) or a value of
  the wrong type fails before the help is printed; an option argparse does not know does not (argparse
  reports unknown options only after the parse, which ``--help`` cuts short), so every ``--option`` of
  the line must also appear in that help text.

Repository paths the README names as inputs (``config/...``) and the targets of its relative links
must exist. The negative controls run the same checker on a missing script, a missing module and a
missing option and require each to be reported.
"""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PYTHON = ROOT / ".venv" / "bin" / "python"
#: top-level commands that take minutes: checked to exist and be executable, never run here
NOT_RUN = {("scripts/demo",), ("scripts/test",)}
#: prefixes of arguments that name repository inputs (outputs go under runs/, which need not exist)
INPUT_PREFIXES = ("config/", "docs/", "results/", "src/", "scripts/")
HELP_TIMEOUT_S = 300.0


def readme_commands(text: str) -> list[str]:
    """The command lines of the ```` ```bash ```` / ```` ```sh ```` blocks of ``text``, in order."""
    commands: list[str] = []
    in_block = False
    pending = ""
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("```"):
            if in_block:
                in_block = False
            else:
                in_block = stripped[3:].strip() in ("bash", "sh", "shell", "console")
            pending = ""
            continue
        if not in_block:
            continue
        if stripped.endswith("\\"):
            pending += stripped[:-1].rstrip() + " "
            continue
        full = (pending + stripped).strip()
        pending = ""
        if full and not full.startswith("#"):
            commands.append(full)
    return commands


def _help_text_has(option: str, help_text: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", help_text) is not None


def check_command(line: str) -> list[str]:
    """Problems with one README command line (empty when it is sound); see the module docstring."""
    tokens = shlex.split(line, comments=True)
    if not tokens:
        return [f"{line!r}: no command"]
    problems: list[str] = []
    program = tokens[0]
    for tok in tokens[1:]:
        if tok.startswith(INPUT_PREFIXES) and not (ROOT / tok).exists():
            problems.append(f"{line!r}: names {tok!r}, which does not exist")

    if program.startswith("scripts/"):
        script = ROOT / program
        if not script.is_file():
            return problems + [f"{line!r}: no script {program}"]
        if not os.access(script, os.X_OK):
            return problems + [f"{line!r}: {program} is not executable"]
        if tuple(tokens) in NOT_RUN:
            return problems
        if program == "scripts/run_node":
            return problems + _check_run_node(line, tokens)
        argv = [str(script), *tokens[1:]]
    elif Path(program).name.startswith("python") and tokens[1:2] == ["-m"] and len(tokens) > 2:
        argv = [str(PYTHON), *tokens[1:]]
    else:
        return problems + [f"{line!r}: neither scripts/... nor python -m ...: the README test cannot check it"]

    proc = subprocess.run([*argv, "--help"], cwd=ROOT, capture_output=True, text=True,
                          timeout=HELP_TIMEOUT_S, env=dict(os.environ))
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        return problems + [f"{line!r} --help: exit {proc.returncode}: {' | '.join(tail)}"]
    help_text = proc.stdout + proc.stderr
    for tok in tokens[1:]:
        option = tok.split("=", 1)[0]
        if option.startswith("--") and option != "--help" and not _help_text_has(option, help_text):
            problems.append(f"{line!r}: option {option} is not in its --help")
    return problems


def _check_run_node(line: str, tokens: list[str]) -> list[str]:
    if len(tokens) < 3:
        return [f"{line!r}: scripts/run_node needs a package and an executable"]
    from biped_sim.graph.launch import find_executable
    try:
        find_executable(tokens[1], tokens[2])
    except FileNotFoundError as exc:
        return [f"{line!r}: {exc}"]
    return []


def relative_links(text: str) -> list[str]:
    """Targets of the README's markdown links and link definitions that are paths in the repository."""
    targets = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r"^\[[^\]]+\]:\s*(\S+)", text, flags=re.M)
    return [t.split("#", 1)[0] for t in targets
            if not re.match(r"[a-z]+://", t) and not t.startswith(("#", "mailto:")) and t.split("#", 1)[0]]


COMMANDS = readme_commands(README.read_text())


def test_the_readme_shows_commands():
    # the two top-level commands and at least one per quickstart task
    assert ("scripts/demo",) in {tuple(shlex.split(c, comments=True)) for c in COMMANDS}
    assert ("scripts/test",) in {tuple(shlex.split(c, comments=True)) for c in COMMANDS}
    assert len(COMMANDS) >= 15, COMMANDS


@pytest.mark.slow
@pytest.mark.parametrize("line", COMMANDS, ids=[c[:70] for c in COMMANDS])
def test_readme_command(line):
    assert check_command(line) == []


def test_readme_links_exist():
    links = relative_links(README.read_text())
    assert links, "the README links no file"
    missing = [t for t in links if not (ROOT / t).exists()]
    assert missing == []


def test_parser_joins_continuations_and_drops_comments():
    text = "x\n```bash\nscripts/a --b 1 \\\n    --c 2   # note\n# only a comment\n\n```\n```text\nscripts/not_a_command\n```\n"
    assert readme_commands(text) == ["scripts/a --b 1 --c 2   # note"]
    assert shlex.split(readme_commands(text)[0], comments=True) == ["scripts/a", "--b", "1", "--c", "2"]


@pytest.mark.slow
@pytest.mark.parametrize("line, expected", [
    ("scripts/no_such_script --force 1", "no script scripts/no_such_script"),
    (".venv/bin/python -m biped_controller.studies.no_such_module", "--help: exit"),
    ("scripts/experiment table --no-such-option 3", "option --no-such-option is not in its --help"),
    ("scripts/experiment no_such_subcommand", "--help: exit"),
    ("scripts/experiment table --observer maybe", "--help: exit"),
    ("scripts/launch --params config/no_such_file.yaml", "does not exist"),
    ("scripts/run_node biped_sim no_such_node", "no executable"),
    ("ls -l", "cannot check it"),
])
def test_checker_reports_a_broken_command(line, expected):
    problems = check_command(line)
    assert any(expected in p for p in problems), problems


def test_scripts_that_are_not_run_exist():
    for (program,) in NOT_RUN:
        assert (ROOT / program).is_file() and os.access(ROOT / program, os.X_OK), program


if __name__ == "__main__":  # pragma: no cover - a quick manual check
    bad = [p for c in COMMANDS for p in check_command(c)]
    print("\n".join(bad) or f"{len(COMMANDS)} README commands ok")
    sys.exit(1 if bad else 0)
