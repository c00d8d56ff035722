"""The "Write your own OCP" example of the OCP guide (docs/guides/ocp.md) runs as written and does what its text says."""

import re
from pathlib import Path

import matplotlib
import numpy as np

README = Path(__file__).parent.parent / "docs" / "guides" / "ocp.md"  # the OCP guide
HEADING = "## Write your own OCP"


def readme_example() -> str:
    """The one python block of the README's section under ``HEADING`` (up to the next ``## `` heading)."""
    text = README.read_text(encoding="utf-8")
    assert text.count(f"\n{HEADING}\n") == 1, f"README needs exactly one section {HEADING!r}"
    section = text.split(f"\n{HEADING}\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"^```python\n(.*?)^```$", section, flags=re.S | re.M)
    assert len(blocks) == 1, f"the section {HEADING!r} should hold one python block, it holds {len(blocks)}"
    return blocks[0]


def test_the_own_ocp_example_runs_and_draws_its_figure(tmp_path, monkeypatch, capsys):
    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "readme_example"}
    exec(compile(readme_example(), "README.md: Write your own OCP", "exec"), namespace)
    figure = tmp_path / "own_ocp.png"
    assert figure.is_file() and figure.stat().st_size > 10_000
    solutions = namespace["solutions"]
    assert set(solutions) == {"ipopt", "sqp"} and all(s.success for s in solutions.values())
    ipopt, sqp = solutions["ipopt"], solutions["sqp"]
    assert abs(sqp.cost - ipopt.cost) <= 1e-7 * ipopt.cost              # "the costs agree to seven digits"
    assert np.abs(sqp.states - ipopt.states).max() < 3e-5               # "the states to about 1e-5"
    centre, radius, R = np.array(namespace["centre"]), namespace["radius"], namespace["params"].R
    distance = np.linalg.norm(ipopt.states[:2] - centre[:, None], axis=0)
    assert distance.min() >= radius + R - 1e-6                          # the shell keeps off the post ...
    assert distance.min() <= radius + R + 1e-3                          # ... and passes it as closely as it may
    assert np.abs(ipopt.states[:2, -1] - namespace["goal"]).max() < 1e-6
    printed = capsys.readouterr().out
    assert "ipopt: Solve_Succeeded" in printed and "sqp: converged" in printed
