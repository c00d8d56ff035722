"""Installed from a wheel, not a source checkout, the command line finds its bundled scenarios (issue 9, finding 12).

The wheel is built from a copy of the sources (``pip wheel --no-deps``), installed into a folder of its own
(``pip install --no-deps --target``; the dependencies come from this environment) and run from an unrelated
folder: ``rollbot-oc problems`` lists the scenarios and ``rollbot-oc run open_loop`` runs one, both read
through ``importlib.resources``.  ``demo`` takes the same path (``report.make_report`` loads ``n_shape`` with
``scenarios.load_bundled``, checked in ``test_reliability``) but takes a minute, so it is not run here.

Building needs setuptools >= 77 from the package index: set ``ROLLBOT_OFFLINE=1`` to skip.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
OFFLINE_HINTS = ("No matching distribution", "Could not find a version", "Failed to establish a new connection",
                 "Temporary failure in name resolution", "Network is unreachable")

pytestmark = [pytest.mark.network,
              pytest.mark.skipif(os.environ.get("ROLLBOT_OFFLINE") == "1", reason="ROLLBOT_OFFLINE=1")]


def pip(*args, cwd):
    return subprocess.run([sys.executable, "-m", "pip", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_wheel_ships_the_scenarios_and_runs_from_another_folder(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    for folder in ("rollbot_oc", "problems"):
        shutil.copytree(ROOT / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    built = pip("wheel", "--no-deps", "--quiet", "-w", str(tmp_path / "wheels"), str(source), cwd=tmp_path)
    if built.returncode != 0 and any(hint in built.stderr for hint in OFFLINE_HINTS):
        pytest.skip(f"cannot reach the package index to build: {built.stderr.strip().splitlines()[-1]}")
    assert built.returncode == 0, built.stderr
    wheel = next((tmp_path / "wheels").glob("rollbot_oc-*.whl"))
    site = tmp_path / "site"
    installed = pip("install", "--no-deps", "--quiet", "--target", str(site), str(wheel), cwd=tmp_path)
    assert installed.returncode == 0, installed.stderr
    assert sorted(p.name for p in (site / "rollbot_oc" / "problems_data").glob("*.toml")) == sorted(
        p.name for p in (ROOT / "problems").glob("*.toml"))
    assert sorted(p.name for p in (site / "rollbot_oc" / "problems_data" / "campaigns").glob("*.toml")) == sorted(
        p.name for p in (ROOT / "problems" / "campaigns").glob("*.toml"))
    def files(folder):  # (pip byte-compiles the firmware's check script into __pycache__ at install)
        return sorted(p.name for p in folder.iterdir() if p.name != "__pycache__")

    assert files(site / "rollbot_oc" / "export" / "c") == files(ROOT / "rollbot_oc" / "export" / "c")  # export-c's
    assert sorted(p.name for p in (site / "rollbot_oc" / "robot" / "c").iterdir()) == sorted(
        p.name for p in (ROOT / "rollbot_oc" / "robot" / "c").iterdir())  # the robot side of the link (C)

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site), "ROLLBOT_OC_CACHE": str(tmp_path / "cache")}

    def rollbot_oc(*args):
        return subprocess.run([sys.executable, "-m", "rollbot_oc.app.cli", *args], cwd=elsewhere, env=env,
                              capture_output=True, text=True, timeout=300)

    where = subprocess.run([sys.executable, "-c", "import rollbot_oc; print(rollbot_oc.__file__)"], cwd=elsewhere,
                           env=env, capture_output=True, text=True, timeout=60)
    assert Path(where.stdout.strip()).is_relative_to(site), where  # the wheel's copy, not the source tree

    listed = rollbot_oc("problems", "--json")
    assert listed.returncode == 0, listed.stderr
    names = [row["name"] for row in json.loads(listed.stdout)]
    assert names == sorted(p.stem for p in (ROOT / "problems").glob("*.toml"))

    run = rollbot_oc("run", "open_loop", "--json", "--out", "report")
    assert run.returncode == 0, run.stderr
    metrics = json.loads(run.stdout)
    assert metrics["problem"] == "open_loop" and metrics["completed"] and metrics["max_R0_error"] < 1e-3
    assert (elsewhere / "report" / "open_loop.json").is_file()

    campaign = rollbot_oc("campaign", "design", "--workers", "1", "--json", "--out", "design")  # a bundled spec
    assert campaign.returncode == 0, campaign.stderr
    assert json.loads(campaign.stdout)["cases"] == 43 and (elsewhere / "design" / "results.parquet").is_file()
