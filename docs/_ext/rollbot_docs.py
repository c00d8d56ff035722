"""Pages of the docs written at build time, so that they follow the code and the measurements.

* ``api/``: one page per module of the installed ``rollbot_oc``, found by walking the package
  (``pkgutil.walk_packages``), each an ``automodule`` stub, and an index with every module's summary line. A new
  module, a moved one or a package that changes its layout gets its page without editing the docs.
* ``benchmarks.md``: every ``benchmarks/*_result*`` file (Markdown included, text and JSON shown as they are),
  with the script that writes it.

Both are written on ``builder-inited``, before Sphinx reads its sources, and only rewritten when their text
changes (so an unchanged page is not read again).
"""

from __future__ import annotations

import importlib
import inspect
import os
import pkgutil
from pathlib import Path

DOCS = Path(__file__).resolve().parent.parent
ROOT = DOCS.parent
PACKAGE = "rollbot_oc"


def _write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` unless it already holds exactly that."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def public_modules(package: str = PACKAGE) -> list[str]:
    """Every importable module of ``package`` whose name has no part starting with ``_`` (``__main__`` too).

    A module whose import gives a module of another name (an alias left where a module used to be) is left out:
    its page is the one of the module it names.
    """
    root = importlib.import_module(package)
    names = [package]
    for info in pkgutil.walk_packages(root.__path__, prefix=package + "."):
        if any(part.startswith("_") for part in info.name.split(".")):
            continue
        names.append(info.name)
    kept = []
    for name in sorted(set(names)):
        module = importlib.import_module(name)
        if module.__name__ == name:
            kept.append(name)
    return kept


def summary_line(name: str) -> str:
    """The first sentence-line of a module's docstring (empty if it has none)."""
    doc = inspect.getdoc(importlib.import_module(name)) or ""
    return doc.strip().split("\n\n", 1)[0].replace("\n", " ").strip()


def write_api(out: Path, pages: bool = True) -> list[str]:
    """Write ``out/index.md`` and one ``out/<module>.rst`` per public module; return the modules.

    With ``pages`` false (``ROLLBOT_DOCS_API=index``, the docs test's quick build) the index lists the modules
    without their pages: the import of every module and the summary table are kept, autodoc's rendering skipped.
    """
    modules = public_modules()
    for name in modules if pages else ():
        title = f"``{name}``"
        _write(out / f"{name}.rst", f"{title}\n{'=' * len(title)}\n\n.. automodule:: {name}\n")
    for stale in out.glob("*.rst"):
        if stale.stem not in modules or not pages:
            stale.unlink()
    lines = ["# API reference", "",
             "Every public module of `rollbot_oc`, found by walking the installed package when the docs are "
             "built; each page documents what the module defines (classes, functions, constants with "
             "docstrings), from its numpydoc docstrings. Names a module only re-exports are documented where "
             "they are defined.", "",
             "```{eval-rst}", ".. autosummary::", ""]
    lines += [f"   {name}" for name in modules]
    lines += ["```", ""]
    if pages:
        lines += ["```{toctree}", ":hidden:", ":maxdepth: 1", ""] + modules + ["```", ""]
    _write(out / "index.md", "\n".join(lines))
    return modules


def benchmark_files(folder: Path = ROOT / "benchmarks") -> list[Path]:
    """The committed benchmark results, ``benchmarks/*_result*``, sorted by name."""
    return sorted(p for p in folder.glob("*_result*") if p.is_file())


def write_benchmarks(page: Path) -> list[Path]:
    """Write the benchmarks page from the result files; return them."""
    files = benchmark_files()
    rel = Path("..") if page.parent == DOCS else Path("../..")
    lines = ["# Benchmarks", "",
             "Speed and quality are measured by the scripts in `benchmarks/` (`make bench` runs them all; each "
             "reports medians, p95 and maxima of repeated runs), and their last results are committed beside "
             "them. This page is generated from those result files when the docs are built: it shows what is "
             "committed, nothing typed by hand. Each result names the machine, load and settings it was measured "
             "with; figures from different machines differ by tens of percent.", ""]
    lines += ["| result | written by |", "|---|---|"]
    for path in files:
        script = path.name.split("_result")[0] + ".py"
        source = f"`benchmarks/{script}`" if (path.parent / script).is_file() else "(no script of that name)"
        lines.append(f"| [{path.name}](#{_anchor(path)}) | {source} |")
    lines.append("")
    for path in files:
        lines += [f"({_anchor(path)})=", f"## `{path.name}`", ""]
        target = (rel / "benchmarks" / path.name).as_posix()
        if path.suffix == ".md":
            lines += [nested_markdown(path.read_text(encoding="utf-8"), level=2), ""]
        else:
            language = {".json": "json"}.get(path.suffix, "text")
            lines += ["```{literalinclude} " + target, f":language: {language}", "```", ""]
    _write(page, "\n".join(lines))
    return files


def nested_markdown(text: str, level: int) -> str:
    """Markdown ``text`` placed under a heading of ``level``: its headings moved below it, with no level skipped.

    A heading of level ``k`` becomes ``level + k`` at most, and never more than one below the heading before it
    (the result files are written by scripts and do not always step one level at a time). Fenced code is kept.
    """
    out, fence, last = [], None, level
    for line in text.splitlines():
        stripped = line.lstrip()
        if stripped.startswith(("```", "~~~")):
            mark = stripped[:3]
            fence = None if fence == mark else (fence or mark)
        elif fence is None and line.startswith("#"):
            hashes = len(line) - len(line.lstrip("#"))
            if line[hashes:hashes + 1] == " ":
                new = min(level + hashes, last + 1, 6)
                line, last = "#" * new + line[hashes:], new
        out.append(line)
    return "\n".join(out)


def _anchor(path: Path) -> str:
    return "bench-" + path.stem.replace("_", "-")


def generate(app) -> None:
    write_api(DOCS / "api", pages=os.environ.get("ROLLBOT_DOCS_API", "pages") != "index")
    write_benchmarks(DOCS / "benchmarks.md")


def setup(app):
    app.connect("builder-inited", generate)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}
