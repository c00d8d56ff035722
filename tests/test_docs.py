"""The docs hold: every Python block of the README and of the docs' pages runs, and the site builds.

* Code blocks: the Python blocks of each page run one after the other in one namespace, in a temporary folder,
  as a reader would paste them (a block that is not meant to run as Python is written with another language:
  ``sh``, whose commands ``test_doc_commands.py`` handles, ``text``, ``toml``). The OCP guide's "Write your own OCP" block is left to ``test_readme_ocp.py``, which runs
  it and checks what its text says.
* The build: ``sphinx-build -W --keep-going`` (every warning an error, which includes every link between pages
  that does not resolve) into a temporary folder, with the notebooks rendered without running them
  (``NB_EXECUTION_MODE=off``) and the API reference as its index only (``ROLLBOT_DOCS_API=index``: every module
  imported and summarised, autodoc's per-module pages left out; ``make docs`` builds those). Then every relative
  link of the built HTML is checked to point at a file of the site.
* The README's relative links point at files of the repository.
"""

import os
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import matplotlib
import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
GENERATED = {DOCS / "benchmarks.md"}          # written at build time from benchmarks/*_result*
OWN_OCP = (DOCS / "guides" / "ocp.md", "## Write your own OCP")   # run by test_readme_ocp.py


def pages() -> list[Path]:
    """The README and every Markdown page of the docs that a person wrote (not the generated ones)."""
    found = [ROOT / "README.md"]
    for path in sorted(DOCS.rglob("*.md")):
        parts = path.relative_to(DOCS).parts
        if parts[0] in ("_build", "api", "notebooks") or path in GENERATED:
            continue
        found.append(path)
    return found


FENCE = re.compile(r"^(`{3,})(\S*)[^\n]*\n(.*?)^\1\s*$", flags=re.S | re.M)


def python_blocks(path: Path) -> list[str]:
    """The ```python blocks of a page, in order (the own-OCP section's left out, see the module doc)."""
    text = path.read_text(encoding="utf-8")
    if path == OWN_OCP[0]:
        head, rest = text.split(f"\n{OWN_OCP[1]}\n", 1)
        text = head + "\n## " + rest.split("\n## ", 1)[1]
    return [body for _, language, body in FENCE.findall(text) if language == "python"]


def test_pages_are_found_and_hold_code():
    names = {p.relative_to(ROOT).as_posix() for p in pages()}
    assert {"README.md", "docs/index.md", "docs/getting_started.md", "docs/guides/ocp.md",
            "docs/guides/campaigns.md", "docs/guides/robot.md"} <= names
    assert len(python_blocks(ROOT / "README.md")) >= 3
    assert sum(len(python_blocks(p)) for p in pages()) >= 12


def test_readme_is_short():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 150


@pytest.mark.parametrize("page", [p for p in pages() if python_blocks(p)],
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_code_blocks_run(page, tmp_path, monkeypatch):
    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "docs_" + page.stem}
    for number, block in enumerate(python_blocks(page), 1):
        exec(compile(block, f"{page.relative_to(ROOT)}: python block {number}", "exec"), namespace)


def test_readme_links_resolve():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    local = [link.split("#")[0] for link in links if not urlsplit(link).scheme and not link.startswith("#")]
    assert local, "the README links into the docs"
    missing = [link for link in local if not (ROOT / link).exists()]
    assert not missing


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links = []

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if (tag, name) in {("a", "href"), ("img", "src"), ("link", "href"), ("script", "src")} and value:
                self.links.append(value)


def test_site_builds_without_warnings_and_its_links_resolve(tmp_path):
    out = tmp_path / "html"
    env = dict(os.environ, NB_EXECUTION_MODE="off", ROLLBOT_DOCS_API="index", PYTHONPATH=str(ROOT))
    result = subprocess.run([sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-q",
                             "-d", str(tmp_path / "doctrees"), str(DOCS), str(out)],
                            capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
    assert result.returncode == 0, result.stderr[-4000:]
    built = sorted(out.rglob("*.html"))
    for name in ("index.html", "getting_started.html", "guides/ocp.html", "guides/campaigns.html",
                 "guides/robot.html", "benchmarks.html", "changelog.html", "api/index.html",
                 "notebooks/07_your_own_ocp.html", "nmpc_modes.html"):
        assert (out / name).is_file(), name
    broken = []
    for page in built:
        parser = _Links()
        parser.feed(page.read_text(encoding="utf-8"))
        for link in parser.links:
            parts = urlsplit(link)
            if parts.scheme or parts.netloc or not parts.path:
                continue
            if not (page.parent / unquote(parts.path)).exists():
                broken.append(f"{page.relative_to(out)} -> {link}")
    assert not broken, broken[:20]
    # the front page leads to the three tasks of the issue in one click
    front = (out / "index.html").read_text(encoding="utf-8")
    for target in ("guides/ocp.html", "guides/campaigns.html#on-a-cluster", "guides/robot.html"):
        assert f'href="{target}"' in front, target
