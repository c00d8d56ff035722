"""Every shell command of the README and of the docs' pages is handled by a test: run, checked, or marked.

The pages are those ``test_docs.py`` reads.  Their ``sh``, ``bash``, ``shell`` and ``console`` blocks (in a
``console`` block, the lines after ``$ ``) are split into commands: one per line (a trailing ``\\`` continues it),
the comment after ``#`` apart, ``a && b`` two commands run in turn.  A block that is not commands (a synopsis, a
transcript) is written with another language (``text``), as ``test_docs.py`` says for Python.  Each command is
handled one of these ways, and ``test_every_command_is_handled`` fails on a command none of them covers (and on
an entry below that no page uses any more):

* **run as written** (``RUN``): quick commands; ``rollbot-oc`` in this process (``cli.main``).  Every command
  runs in a fresh temporary folder, so ``cd FOLDER`` (a placeholder such as ``/anywhere``) is what it says.
* **make targets of the repository** (``DRY_RUN``): ``make -n TARGET``, which checks that the target exists and
  prints its recipe without running it: ``make demo`` creates a virtual environment and runs the demo (minutes),
  ``make test`` is this suite (it would run inside itself), ``make docs`` is the site build
  ``test_docs.py`` runs.
* **long commands of the command line** (``CHECK``): what takes minutes here (an NMPC run or an export
  compiles the control step, seconds to a minute of gcc on a cold machine; a campaign runs hundreds of cases; the
  demo runs PID and NMPC on the N-shape) is parsed by the command line's own parser, with every option and value
  as written, and what it names is loaded as the command loads it (the scenario with its ``--duration``, the
  campaign spec, the parameter file): everything it does before its long computation.  The reason beside each
  entry names the test that runs that path in full where there is one.
* **run by another test** (``ELSEWHERE``): a command on what an earlier one builds (``make -C rollbot_c check``
  on an exported C project), with the test that runs it; that test must exist.
* **marked in the doc** with what it needs that a test machine lacks (root, the network, a cluster, the ARM
  toolchain and QEMU): a comment with ``needs: WHAT`` on the command's line, or a first line ``# needs: WHAT``
  for its whole block.  The reader sees it; the test reports it as skipped with that reason.
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import pytest

from test_docs import FENCE, ROOT, pages

SHELLS = ("sh", "bash", "shell", "console")

RUN = {
    "rollbot-oc problems": "lists the bundled scenarios (well under a second)",
}

DRY_RUN = {
    "make demo": "creates .venv and runs the demo, minutes; the demo's report is test_report.py's",
    "make test": "the whole suite, this test included",
    "make docs": "the site with every API page and the notebooks run; test_docs.py builds the site",
}

CHECK = {
    "rollbot-oc compare n_shape": "PID and NMPC on the N-shape, minutes (the NMPC compiles its step); "
                                  "test_report.py's demo runs the comparison",
    "rollbot-oc run circle_R035 --controller nmpc --out out/circle": "an NMPC run of 300 s, minutes",
    "rollbot-oc demo --quick --out report": "about a minute; test_report.py::test_demo_writes_the_report_folder",
    "rollbot-oc export-c --out rollbot_c": "records a closed-loop run and compiles the step and the replay project; "
                                           "test_export.py's c_export fixture",
    "rollbot-oc run n_shape --controller c --c-project rollbot_c --json":
        "needs the project the export above writes and a whole N-shape run, minutes; "
        "test_c_controller.py::test_run_controller_c_prints_the_nmpcs_json runs --controller c from export-c",
    "rollbot-oc campaign design --workers 1": "42 design points, minutes; test_campaign.py runs design campaigns",
    "rollbot-oc campaign problems/campaigns/robustness.toml": "200 closed-loop runs; test_campaign.py loads the spec",
}

ELSEWHERE = {
    "make -C rollbot_c check":
        "tests/test_export.py::test_export_builds_and_replays_the_nmpcs_run",
}

NEEDS = re.compile(r"\bneeds:\s*(.+)$")


@dataclass(frozen=True)
class Command:
    """One command of a shell block: where it is, its text (comment apart), and what its doc says it needs."""

    page: str
    block: int
    text: str
    needs: str | None

    @property
    def id(self) -> str:
        return f"{self.page}:{self.block}: {self.text}"


def _split_comment(line: str) -> tuple[str, str]:
    """``(command, comment)`` of a line: the comment from the first ``#`` outside quotes that starts a word."""
    quote = None
    for i, char in enumerate(line):
        if quote:
            quote = None if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].strip(), line[i + 1:].strip()
    return line.strip(), ""


def commands(page: Path) -> list[Command]:
    """The commands of a page's shell blocks, in order (see module doc)."""
    found = []
    name = page.relative_to(ROOT).as_posix()
    shell_blocks = [(language, body) for _, language, body in FENCE.findall(page.read_text(encoding="utf-8"))
                    if language in SHELLS]
    for number, (language, body) in enumerate(shell_blocks, 1):
        lines = body.splitlines()
        if language == "console":
            lines = [line[2:] for line in lines if line.startswith("$ ")]
        block_needs = None
        if lines and lines[0].lstrip().startswith("#"):
            match = NEEDS.search(lines[0])
            block_needs = match.group(1) if match else None
        joined, pending = [], ""
        for line in lines:
            if line.rstrip().endswith("\\"):
                pending += line.rstrip()[:-1] + " "
                continue
            joined.append(pending + line)
            pending = ""
        for line in joined:
            text, comment = _split_comment(line)
            if not text:
                continue
            match = NEEDS.search(comment)
            needs = match.group(1) if match else block_needs
            for part in text.split("&&"):
                found.append(Command(name, number, " ".join(part.split()), needs))
    return found


ALL = [command for page in pages() for command in commands(page)]
TABLES = {"RUN": RUN, "DRY_RUN": DRY_RUN, "CHECK": CHECK, "ELSEWHERE": ELSEWHERE}


def handling(command: Command) -> str | None:
    """How the test handles a command: ``"needs"``, ``"cd"``, a table's name, or None (unknown)."""
    if command.needs:
        return "needs"
    if command.text.split()[0] == "cd":
        return "cd"
    return next((name for name, table in TABLES.items() if command.text in table), None)


def test_every_command_is_handled():
    """No command is left out: each is run, checked, run elsewhere, or marked; no entry is stale."""
    assert len(ALL) >= 15 and {c.page for c in ALL} >= {"README.md", "docs/getting_started.md"}
    unknown = [c.id for c in ALL if handling(c) is None]
    assert unknown == [], ("commands no test handles: add each to RUN, DRY_RUN, CHECK or ELSEWHERE in "
                           f"{Path(__file__).name} (saying why), or mark it in its doc with '# needs: WHAT'")
    used = {c.text for c in ALL if not c.needs}
    stale = [f"{name}: {text}" for name, table in TABLES.items() for text in table if text not in used]
    assert stale == [], "entries no page uses any more"


def _check_cli(argv: list[str]) -> None:
    """Parse ``argv`` as ``rollbot-oc`` does and load what it names, as the command would before its work."""
    from rollbot_oc.app import cli
    from rollbot_oc.campaign import load_campaign_spec
    from rollbot_oc.model.params import load_params
    from rollbot_oc.scenarios.bundled import load_scenario

    try:
        args = cli.build_parser().parse_args(argv)
    except SystemExit as exc:  # argparse has printed the reason
        pytest.fail(f"rollbot-oc {' '.join(argv)}: the parser refuses it (exit {exc.code})")
    if args.command in ("run", "compare"):
        cli._load_scenario(args)
    elif args.command == "export-c":
        load_scenario(args.problem, base=load_params(args.params))
    elif args.command == "campaign":
        load_campaign_spec(args.spec)
    elif args.command == "demo":
        load_params(args.params)
    else:
        pytest.fail(f"rollbot-oc {args.command}: CHECK does not know what this command loads")


@pytest.mark.parametrize("command", ALL, ids=lambda c: c.id)
def test_shell_command(command, tmp_path, monkeypatch, capsys):
    """One command, as ``handling`` says (see module doc), in a fresh temporary folder."""
    monkeypatch.chdir(tmp_path)
    how, argv = handling(command), shlex.split(command.text)
    if how == "needs":
        pytest.skip(f"marked in {command.page}: needs {command.needs}")
    elif how == "cd":  # the commands after it run in a fresh temporary folder, as every command here does
        assert len(argv) == 2, command.id
    elif how == "RUN":
        from rollbot_oc.app.cli import main

        assert argv[0] == "rollbot-oc", command.id
        assert main(argv[1:]) == 0, (command.id, capsys.readouterr().err)
    elif how == "DRY_RUN":
        if shutil.which("make") is None:
            pytest.skip("make is not installed")
        done = subprocess.run(["make", "-n", "-C", str(ROOT), *argv[1:]], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0 and done.stdout.strip(), (command.id, done.stderr)
    elif how == "CHECK":
        assert argv[0] == "rollbot-oc", command.id
        monkeypatch.chdir(ROOT)  # paths in the docs are from the source folder
        _check_cli(argv[1:])
    elif how == "ELSEWHERE":
        path, name = ELSEWHERE[command.text].split("::")
        assert f"def {name}(" in (ROOT / path).read_text(encoding="utf-8"), ELSEWHERE[command.text]
    else:
        pytest.fail(f"{command.id}: no test handles it (see test_every_command_is_handled)")


def test_the_command_synopsis_names_every_command_and_only_real_options():
    """The CLI guide's synopsis (a ``text`` block: metasyntax, not commands) lists every subcommand once, and each
    ``--option`` it shows exists for its subcommand."""
    from rollbot_oc.app import cli

    text = (ROOT / "docs" / "guides" / "cli.md").read_text(encoding="utf-8")
    synopsis = [body for _, language, body in FENCE.findall(text) if language == "text"
                and body.startswith("rollbot-oc ")][0].splitlines()
    parser = cli.build_parser()
    subparsers = next(a for a in parser._actions if a.dest == "command").choices
    listed = [line.split()[1] for line in synopsis]
    assert sorted(listed) == sorted(subparsers)
    for line in synopsis:
        sub = subparsers[line.split()[1]]
        known = {option for action in sub._actions for option in action.option_strings}
        assert set(re.findall(r"--[a-z][a-z0-9-]*", line)) <= known, line
