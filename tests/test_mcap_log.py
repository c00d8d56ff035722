"""MCAP run logs: a run written as a log opens with mcap's reader, holds every channel, reads back as the same run
(to the bit) and plots; a log streamed by a writer that dies keeps what it flushed."""

import json
import shutil

import numpy as np
import pytest

pytest.importorskip("mcap", reason="the mcap package is not installed (pip install 'rollbot_oc[robot]')")

from mcap.reader import make_reader  # noqa: E402

from rollbot_oc.app.cli import main  # noqa: E402
from rollbot_oc.core.errors import ConfigError  # noqa: E402
from rollbot_oc.robot.log import CHANNELS, LogWriter, read_log, write_run_log  # noqa: E402
from rollbot_oc.scenarios.problem import run_problem  # noqa: E402
from rollbot_oc.robot.faults import FaultCounts, LinkStats  # noqa: E402
from rollbot_oc.scenarios.bundled import load_bundled  # noqa: E402


@pytest.fixture(scope="module")
def pid_run():
    return run_problem(load_bundled("n_shape"), "pid", duration=4.0, show_progress=False)


def same_run(a, b) -> None:
    for key in ("t", "x", "command", "diag", "step_times"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
    assert np.array_equal(a.speed_command, b.speed_command, equal_nan=True)
    assert a.dt == b.dt and a.params == b.params and a.events == b.events


def test_a_run_log_holds_every_channel_and_reads_back_as_the_run(pid_run, tmp_path):
    path = write_run_log(pid_run, tmp_path / "run.mcap")
    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    topics = {c.topic: c for c in summary.channels.values()}
    assert set(topics) == set(CHANNELS)
    assert all(c.message_encoding == "json" and summary.schemas[c.schema_id].encoding == "jsonschema"
               for c in topics.values())
    counts = {topic: summary.statistics.channel_message_counts.get(c.id, 0) for topic, c in topics.items()}
    steps = pid_run.result.command.size
    assert counts["/measurement"] == counts["/tf"] == steps + 1
    assert counts["/command"] == counts["/diagnostics"] == counts["/reference"] == steps
    back = read_log(path)
    assert back.complete and back.run["controller"] == "pid" and back.run["problem"] == "n_shape"
    same_run(back.result, pid_run.result)
    assert back.metrics["stop_errors"] == pid_run.metrics["stop_errors"]
    (t, first), = back.messages["/reference"][:1]
    assert t == 0.0 and set(first) >= {"centre", "radius", "braking"}


def test_plot_draws_a_run_from_its_log(pid_run, tmp_path, capsys):
    write_run_log(pid_run, tmp_path / "run.mcap")
    pid_run.result.save(tmp_path / "run.npz")
    assert main(["plot", str(tmp_path / "run.mcap"), "--out", str(tmp_path / "mcap"), "--quiet"]) == 0
    assert main(["plot", str(tmp_path / "run.npz"), "--out", str(tmp_path / "npz"), "--quiet"]) == 0
    for name in ("run_top.png", "run_time.png", "run_energy.png"):  # the same figures, drawn from the same run
        assert (tmp_path / "mcap" / name).read_bytes() == (tmp_path / "npz" / name).read_bytes()
    (tmp_path / "bad.mcap").write_bytes(b"not an mcap file")
    assert main(["plot", str(tmp_path / "bad.mcap")]) == 2
    err = capsys.readouterr().err
    assert "bad.mcap" in err and err.count("\n") == 1


def test_the_nmpc_log_holds_its_windows_modes_and_plans(n_shape_runs, tmp_path):
    _, (_, nmpc) = n_shape_runs
    back = read_log(write_run_log(nmpc, tmp_path / "nmpc.mcap"))
    same_run(back.result, nmpc.result)
    modes = [(m["machine"], m["mode"]) for _, m in back.messages["/mode"]]
    assert len(modes) == len(nmpc.metrics["modes"]) + len(nmpc.metrics["step_modes"])
    assert ("supervisor", nmpc.metrics["modes"][0]["mode"]) in modes
    solves = back.messages["/reference"]
    assert len(solves) == nmpc.metrics["solves"]  # a window at every solve
    t, window = solves[0]
    horizon = len(window["x"])
    assert len(window["accel"]) == horizon - 1 and window["h"] > 0
    plans = back.messages["/plan"]
    assert plans and all(m["summary"]["T"] > 0 and len(m["nodes"]["x"]) == len(m["nodes"]["t"]) for _, m in plans)
    # the first window starts where the first plan does: it samples it
    assert window["x"][0] == pytest.approx(plans[0][1]["nodes"]["x"][0], abs=1e-9)


def test_a_streamed_log_keeps_what_was_flushed_when_its_writer_dies(tmp_path):
    path = tmp_path / "live.mcap"
    log = LogWriter(path, {"dt": 0.01, "params_file": {}}, flush_every=0.5)
    state = np.zeros(11)
    state[2] = 1.0
    for k in range(120):  # 1.2 s: flushed at 0.5 s and 1.0 s
        state[0] = 0.01 * k
        log.measurement(0.01 * k, state, k)
        log.command(0.01 * k, 1.0, period=k)
    crashed = tmp_path / "crashed.mcap"
    shutil.copy(path, crashed)  # the file as a process killed now leaves it
    stats = LinkStats(frames_sent=120, bytes_sent=3000, lost=2, late=1, injected=FaultCounts(lost=2).to_dict())
    log.link(1.2, stats)
    log.close()
    back = read_log(crashed)
    assert not back.complete
    kept = [m["state"]["x"] for _, m in back.messages["/measurement"]]
    assert 51 <= len(kept) <= 120 and kept == [0.01 * k for k in range(len(kept))]
    whole = read_log(path)
    assert whole.complete and len(whole.messages["/measurement"]) == 120 and whole.result.t.size == 120
    ((t, link),) = whole.messages["/link"]
    assert t == 1.2 and {k: v for k, v in link.items() if k != "t"} == stats.to_dict()
    with pytest.raises(ValueError, match="unknown channel"):
        LogWriter(tmp_path / "x.mcap").write("/nothing", 0.0, {})


def test_a_log_that_is_not_ours_is_one_line(tmp_path):
    from mcap.writer import Writer

    with open(tmp_path / "other.mcap", "wb") as handle:
        writer = Writer(handle)
        writer.start()
        writer.finish()
    with pytest.raises(ConfigError, match="not a rollbot_oc run log"):
        read_log(tmp_path / "other.mcap")
    with pytest.raises(ConfigError, match="cannot read"):
        read_log(tmp_path / "missing.mcap")
    assert json.loads(json.dumps(CHANNELS))  # the schemas are JSON
