"""The command line's contract under generated inputs (property-based, hypothesis).

Parameter files, problem files, saved runs and argument vectors are generated
(valid, out of range, wrong types, NaN and infinities, missing and unknown
keys, odd paths) and ``rollbot_oc.app.cli.main`` is called in-process.  Whatever
the input:

* no traceback, and every line on stderr is one of ours (``rollbot-oc: ...``);
* the exit status is 0, 1 (did not converge or complete: ``failed``) or 2 (one
  ``error`` line), never 3 (internal error);
* with ``--json`` and status 0 or 1, stdout is strict JSON (no NaN);
* no file appears outside the output folder.

Examples stay small (tiny durations, one speed); ``HYPOTHESIS_PROFILE=nightly``
runs many more of them (profiles in ``conftest.py``).
"""

import contextlib
import io
import json
import math
import tempfile
from pathlib import Path

from hypothesis import event, given
from hypothesis import strategies as st

from rollbot_oc.app.cli import main
from rollbot_oc.model.dynamics import rest_state
from rollbot_oc.model.params import _FILE_KEYS
from rollbot_oc.simulation.plant import simulate

# -- values and files -----------------------------------------------------------------------------------------
text = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\0"), max_size=8)
odd_floats = st.floats(allow_nan=True, allow_infinity=True)
junk = st.one_of(odd_floats, st.integers(-10**12, 10**12), st.booleans(), text,
                 st.lists(st.floats(-10, 10), max_size=3), st.fixed_dictionaries({"a": st.integers()}))


def near(value):
    """Plausible values around a default (and the default itself)."""
    return st.one_of(st.just(value), st.floats(0.5 * value, 2.0 * value) if value else st.floats(0.0, 1.0))


PLAUSIBLE = {"R": near(0.12), "M_s": near(0.84), "m_b": near(0.04), "I": near(0.0053), "phi_deg": st.floats(1, 89),
             "r0": near(0.093), "m": near(0.306), "k0": st.one_of(st.just(0.0), near(0.005)), "g": near(9.81),
             "mu": near(0.5), "max_torque": near(0.28), "max_speed": near(3 * math.pi), "max_accel": near(30.0),
             "slope_deg": st.floats(0, 40), "slope_dir_deg": st.floats(-360, 360)}
plausible_tables = st.fixed_dictionaries({}, optional=PLAUSIBLE)
param_tables = st.one_of(plausible_tables, st.dictionaries(
    st.sampled_from(sorted(_FILE_KEYS) + ["radius", "R0", "params", ""]),
    st.one_of(junk, *PLAUSIBLE.values()), max_size=4))


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"


def toml(data: dict) -> str:
    """TOML text of a mapping: scalars first, then one [table] per dict value."""
    lines = [f"{json.dumps(k)} = {toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for key, table in data.items():
        if isinstance(table, dict):
            lines.append(f"[{json.dumps(key)}]")
            lines += [f"{json.dumps(k)} = {toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


names = st.one_of(st.sampled_from(["ok", "ok-2", "../../escape", "/tmp/rollbot_escape", "a/b", "..", "", " x"]),
                  text, st.integers())
points = st.lists(st.lists(st.one_of(st.floats(-2, 2), odd_floats, text), min_size=1, max_size=3), max_size=3)
VALID_PROBLEMS = {
    "circle": {"name": "ok", "kind": "circle", "duration": 2.0, "circle": {"radius": 0.3}},
    "waypoints": {"name": "ok", "kind": "waypoints", "duration": 2.0, "waypoints": {"stops": [[0.0, 0.3]]}},
    "open_loop": {"name": "ok", "kind": "open_loop", "duration": 2.0, "open_loop": {"speeds": [1.0]}},
}
changes = st.fixed_dictionaries(
    {},
    optional={
        "name": names, "kind": st.sampled_from(["circle", "waypoints", "open_loop", "spiral"]),
        "duration": st.one_of(st.sampled_from([1.0, 2.0, 0.0, 1e5, 3600.0]), junk),
        "dt": st.one_of(st.sampled_from([0.01, 0.005, 0.003, 0.0, 1.0]), junk),
        "description": st.one_of(text, junk),
        "circle": st.fixed_dictionaries({"radius": st.one_of(st.sampled_from([0.05, 0.3, 0.5, 5.0]), junk)},
                                        optional={"centre": st.lists(st.floats(-1, 1), min_size=2, max_size=2),
                                                  "settle_time": st.one_of(st.floats(0, 2), junk),
                                                  "wobble": junk}),
        "waypoints": st.fixed_dictionaries({"stops": st.one_of(st.just([[0.0, 0.3]]), points, junk)}),
        "open_loop": st.fixed_dictionaries({"speeds": st.one_of(st.just([1.0]), st.lists(junk, max_size=2))}),
        "params": st.one_of(param_tables, junk),
        "floor": st.fixed_dictionaries({}, optional={"slope_deg": st.one_of(st.floats(0, 40), junk)}),
        "sensor": st.fixed_dictionaries({}, optional={"latency": st.one_of(st.integers(0, 3), junk),
                                                      "position_noise": st.one_of(st.floats(0, 0.01), junk)}),
        "start": st.fixed_dictionaries({}, optional={"position": st.one_of(points, junk)}),
        "colour": junk,
    })
problem_tables = st.tuples(st.sampled_from(sorted(VALID_PROBLEMS)), st.one_of(st.just({}), changes)).map(
    lambda pair: {**VALID_PROBLEMS[pair[0]], **pair[1]})

# A file argument: ("toml", text), ("bytes", content), or an odd path.
file_args = st.one_of(
    st.tuples(st.just("bytes"), st.binary(max_size=40)),
    st.sampled_from([("missing",), ("folder",), ("empty",), ("blocked",)]),
)


def outs(valid_allowed: bool):
    """An output folder: ("out",) is a fresh folder inside the work folder; the others are odd paths."""
    odd = st.sampled_from([("blocker",), ("under_blocker",), ("uncreatable",), ("empty",)])
    return st.one_of(odd, st.just(("out",))) if valid_allowed else odd


numbers = st.one_of(st.sampled_from(["1", "3"]),
                    st.sampled_from(["1", "0", "-1", "3", "9.42", "1e9", "nan", "inf", "-inf", "x", "", "1e-300"]),
                    st.floats(allow_nan=True, allow_infinity=True).map(repr))

_SAVED_RUN: list[bytes] = []


def saved_run_bytes() -> bytes:
    if not _SAVED_RUN:
        with tempfile.TemporaryDirectory() as tmp:
            _SAVED_RUN.append(simulate(rest_state(), 1.0, speed=1.0).save(Path(tmp) / "r.npz").read_bytes())
    return _SAVED_RUN[0]


# -- the harness ----------------------------------------------------------------------------------------------
class Workspace:
    """A temporary tree ``base/a/b/work`` (so that escaping names land inside ``base``, where they are seen)."""

    def __init__(self, base: Path):
        self.base = base
        self.work = base / "a" / "b" / "work"
        self.work.mkdir(parents=True)
        (self.work / "blocker").write_text("a file")
        self.allowed: list[Path] = []

    def file(self, spec, name: str) -> str:
        kind = spec[0]
        path = self.work / name
        if kind == "toml":
            path.write_text(spec[1], encoding="utf-8")
        elif kind == "bytes":
            path.write_bytes(spec[1])
        elif kind == "folder":
            path.mkdir()
        elif kind == "empty":
            return ""
        elif kind == "blocked":
            return str(self.work / "blocker" / name)
        return str(path)

    def out(self, spec, name: str = "out") -> str:
        kind = spec[0]
        if kind == "out":
            self.allowed.append(self.work / name)
            return str(self.work / name)
        return {"blocker": str(self.work / "blocker"), "under_blocker": str(self.work / "blocker" / "x"),
                "uncreatable": "/proc/rollbot_oc_contract", "empty": ""}[kind]

    def snapshot(self) -> set[Path]:
        return {p for p in self.base.rglob("*")}


def refuse_constant(name):
    raise AssertionError(f"{name} in the JSON output")


def holds_contract(argv: list[str], space: Workspace) -> None:
    """Run ``main(argv)`` in the work folder and check the contract (see the module doc)."""
    before = space.snapshot()
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.chdir(space.work), contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        status = main(argv)
    out, err = stdout.getvalue(), stderr.getvalue()
    event(f"exit status {status}")
    where = f"argv={argv!r}\nstatus={status}\nstderr={err}"
    assert "Traceback" not in err, where
    assert status in (0, 1, 2), where
    lines = err.splitlines()
    assert all(line.startswith("rollbot-oc: ") for line in lines), where
    errors = [line for line in lines if line.startswith("rollbot-oc: error: ")]
    failures = [line for line in lines if line.startswith("rollbot-oc: failed: ")]
    assert len(errors) == (status == 2) and len(failures) == (status == 1), where
    if status == 2:
        assert lines[-1] == errors[0], where
    if "--json" in argv and status in (0, 1) and not {"--help", "-h", "--version"} & set(argv):
        json.loads(out, parse_constant=refuse_constant)
    new = space.snapshot() - before
    outside = [p for p in new if not any(p == folder or folder in p.parents for folder in space.allowed)]
    assert not outside, f"{where}\nwritten outside the output folder: {outside}"


def run_contract(build):
    """Build an argv in a fresh workspace and check the contract."""
    with tempfile.TemporaryDirectory() as tmp:
        space = Workspace(Path(tmp))
        holds_contract(build(space), space)


# -- the properties -------------------------------------------------------------------------------------------
@given(params=st.one_of(param_tables.map(lambda t: ("toml", toml(t))),
                        st.fixed_dictionaries({"params": param_tables}).map(lambda t: ("toml", toml(t))), file_args),
       command=st.sampled_from(["quasi", "stability"]), omega0=numbers,
       branch=st.sampled_from(["slow", "fast", "odd"]), json_flag=st.booleans(), plot=st.none() | outs(False))
def test_analysis_commands_with_generated_parameter_files(params, command, omega0, branch, json_flag, plot):
    def build(space):
        argv = [command, "--omega0", omega0, "--branch", branch, "--params", space.file(params, "p.toml")]
        argv += ["--json"] if json_flag else []
        argv += ["--plot", space.out(plot)] if plot else []
        return argv

    run_contract(build)


@given(params=st.one_of(param_tables.map(lambda t: ("toml", toml(t))), file_args), json_flag=st.booleans(),
       quiet=st.booleans())
def test_params_with_generated_parameter_files(params, json_flag, quiet):
    def build(space):
        return ["params", "--params", space.file(params, "p.toml")] + (["--json"] if json_flag else []) + (
            ["--quiet"] if quiet else [])

    run_contract(build)


@given(problem=st.one_of(problem_tables.map(lambda t: ("toml", toml(t))), file_args),
       params=st.none() | param_tables.map(lambda t: ("toml", toml(t))), duration=st.sampled_from(
           ["1", "2", "0", "1e9", "nan", "x", None]), seed=st.sampled_from(["0", "7", "-1", "x", "4294967296"]),
       json_flag=st.booleans(), out=st.none() | outs(True))
def test_run_with_generated_problem_files(problem, params, duration, seed, json_flag, out):
    def build(space):
        argv = ["run", space.file(problem, "problem.toml"), "--controller", "pid", "--seed", seed]
        # a valid problem runs 1 or 2 s at most: no duration means no run (the open-loop problem refuses one)
        argv += ["--duration", duration if duration is not None else "1"]
        argv += ["--params", space.file(params, "params.toml")] if params else []
        argv += ["--json"] if json_flag else []
        argv += ["--out", space.out(out)] if out else []
        return argv

    run_contract(build)


@given(omega0=numbers, duration=st.sampled_from(["50", "50", "1", "1e9", "nan", "-5", "x"]),
       ramp=st.sampled_from(["0.5", "0.5", "2", "0", "-1", "inf", "1e9", "x"]), slope=st.none() | numbers,
       json_flag=st.booleans(), out=st.none() | outs(False))
def test_openloop_arguments(omega0, duration, ramp, slope, json_flag, out):
    def build(space):
        argv = ["openloop", "--omega0", omega0, "--duration", duration, "--ramp-rate", ramp]
        argv += ["--slope-deg", slope] if slope is not None else []
        argv += ["--json"] if json_flag else []
        argv += ["--out", space.out(out)] if out else []
        return argv

    run_contract(build)


@given(run=st.one_of(st.just(("saved",)), file_args), out=st.none() | outs(False), animate=st.booleans())
def test_plot_with_generated_files(run, out, animate):
    def build(space):
        if run == ("saved",):
            path = space.work / "run.npz"
            path.write_bytes(saved_run_bytes())
            argv = ["plot", str(path), "--out", space.out(out or ("blocker",))]  # a valid run: odd folders only
        else:
            argv = ["plot", space.file(run, "run.npz")] + (["--out", space.out(out)] if out else [])
            space.allowed.append(space.work)  # the default --out is the current folder
        return argv + (["--animate"] if animate else [])

    run_contract(build)


VOCABULARY = ["run", "compare", "quasi", "stability", "openloop", "plot", "demo", "problems", "params", "--json",
              "--quiet", "--out", "--params", "--omega0", "--duration", "--seed", "--controller", "nmpc", "--branch",
              "--debug",
              "--help", "-h", "--version", "1", "nan", "x", "", "-", "--", "n_shape", "circle_R035"]


@given(argv=st.lists(st.one_of(st.sampled_from(VOCABULARY), text), max_size=6))
def test_generated_argument_vectors(argv):
    long_running = any(c in argv for c in ("run", "compare", "demo", "openloop")) and not {"--help", "-h",
                                                                                            "--version"} & set(argv)
    if long_running:  # keep to what ends quickly: no real runs here (the other properties cover them)
        argv = [a for a in argv if a not in ("n_shape", "circle_R035")] + ["--duration", "0"]

    def build(space):
        space.allowed.append(space.work)  # "--out" with a generated value may name a folder in the work folder
        return argv

    run_contract(build)
