"""Campaigns (issue 12): the same table on any number of workers, resumed runs, failures as rows, spec checks."""

import json
import math
from pathlib import Path

import pandas as pd
import pytest

from rollbot_oc.campaign import RUN_COLUMNS, Campaign, campaign_from_dict, load_campaign_spec, run_campaign
from rollbot_oc.app.cli import main
from rollbot_oc.core.errors import ConfigError

DESIGN = {  # five cheap design points (the prototype and a 2 x 2 grid), the last with a folding branch
    "name": "tiny_design", "kind": "design", "seed": 3,
    "design": {"speeds": 5, "grid": {"phi_deg": [40.0, 50.0], "k0": [0.00507, 0.02534]}},
}


def comparable(table: pd.DataFrame) -> pd.DataFrame:
    """The table without the provenance columns (code, wall time, worker), which differ from run to run."""
    return table.drop(columns=list(RUN_COLUMNS))


def test_two_worker_processes_give_the_same_table_as_one(tmp_path):
    psutil = pytest.importorskip("psutil")
    children = {p.pid for p in psutil.Process().children(recursive=True)}
    campaign = campaign_from_dict(DESIGN, "tiny.toml")
    alone = run_campaign(campaign, tmp_path / "one", workers=1, figures=False)
    spread = run_campaign(campaign, tmp_path / "two", workers=2, figures=False)
    assert alone.summary["where"] == "in-process"
    assert spread.summary["where"] == "local Dask cluster of 2 worker processes" and spread.summary["workers"] == 2
    pd.testing.assert_frame_equal(comparable(alone.table), comparable(spread.table))
    on_disk = [pd.read_parquet(tmp_path / name / "results.parquet") for name in ("one", "two")]
    pd.testing.assert_frame_equal(comparable(on_disk[0]), comparable(on_disk[1]))
    assert list(alone.table["case"]) == list(range(5)) and alone.table["reference"].tolist()[0]
    assert len(set(spread.table["worker"])) >= 1 and set(spread.table["code"]) == set(alone.table["code"])
    # the cluster is gone: no worker or nanny process left behind (multiprocessing's resource tracker, one per
    # parent process, stays by design)
    left = [p.cmdline() for p in psutil.Process().children(recursive=True)
            if p.pid not in children and "resource_tracker" not in " ".join(p.cmdline())]
    assert left == [], left


def test_an_existing_scheduler_from_the_environment_gives_the_same_table(tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")
    campaign = campaign_from_dict(DESIGN, "tiny.toml")
    alone = run_campaign(campaign, tmp_path / "one", workers=1, figures=False)
    with distributed.LocalCluster(n_workers=1, processes=False, dashboard_address="127.0.0.1:0") as cluster:
        monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", cluster.scheduler_address)
        remote = run_campaign(campaign, tmp_path / "remote", figures=False)
    assert remote.summary["where"] == f"Dask scheduler {cluster.scheduler_address}"
    pd.testing.assert_frame_equal(comparable(alone.table), comparable(remote.table))


def test_a_failing_case_is_a_row_with_its_error(tmp_path):
    result = run_campaign(campaign_from_dict(DESIGN, "tiny.toml"), tmp_path, workers=1)
    table = result.table.set_index("case")
    assert (table.loc[[0, 1, 3], "status"] == "succeeded").all()
    for case in (2, 4):  # k0 five times the prototype's: the slow branch folds before full speed
        assert table.loc[case, "status"] == "failed"
        assert "the slow branch ends at omega0" in table.loc[case, "error"]
        assert table.loc[case, "R0_min"] > 0 and math.isnan(table.loc[case, "R0_max"])  # measured values stay
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert (summary["cases"], summary["succeeded"], summary["failed"], summary["errors"]) == (5, 3, 2, 0)
    assert [f["case"] for f in summary["failures"]] == [2, 4]
    assert "slow branch ends" in (tmp_path / "summary.md").read_text()
    assert {"pareto.png", "design_map.png", "results.parquet"} <= {p.name for p in tmp_path.iterdir()}

    def shaky(x, seed):
        if x < 0:
            raise ValueError(f"no square root of {x}")
        return {"root": math.sqrt(x), "failure": "too small" if x < 1 else None, "seed_seen": seed}

    rows = run_campaign(Campaign.of_function("shaky", shaky, [{"x": 4.0}, {"x": -1.0}, {"x": 0.5}]),
                        tmp_path / "function", workers=1).table
    assert rows["status"].tolist() == ["succeeded", "error", "failed"]
    assert rows["error"].tolist()[1:] == ["ValueError: no square root of -1.0", "too small"]
    assert rows["root"].tolist()[0] == 2.0 and math.isnan(rows["root"].tolist()[1])
    assert rows["seed_seen"].tolist()[0] == rows["seed"].tolist()[0]  # the case's own seed reaches the function


def counted(x, log, stop_at):
    """A case that records each call in ``log`` and is interrupted (Ctrl-C) at ``stop_at`` while ``log.stop``
    exists."""
    with open(log, "a") as handle:
        handle.write(f"{x}\n")
    if x == stop_at and Path(log + ".stop").exists():
        raise KeyboardInterrupt
    return {"double": 2 * x}


def test_an_interrupted_campaign_resumes_without_running_finished_cases_again(tmp_path):
    log = str(tmp_path / "calls.log")
    Path(log + ".stop").touch()
    campaign = Campaign.of_function("counted", counted, [{"x": x, "log": log, "stop_at": 3} for x in range(6)])
    with pytest.raises(KeyboardInterrupt):
        run_campaign(campaign, tmp_path / "out", workers=1)
    assert Path(log).read_text().split() == ["0", "1", "2", "3"]
    assert not (tmp_path / "out" / "results.parquet").exists()
    assert list((tmp_path / "out" / "parts").glob("part-*.parquet"))  # the finished rows were written
    Path(log + ".stop").unlink()
    result = run_campaign(campaign, tmp_path / "out", workers=1)
    assert Path(log).read_text().split() == ["0", "1", "2", "3", "3", "4", "5"]  # only the unfinished ran
    assert (result.summary["computed"], result.summary["resumed"]) == (3, 3)
    assert result.table["double"].tolist() == [0, 2, 4, 6, 8, 10]
    again = run_campaign(campaign, tmp_path / "out", workers=1)  # nothing left: no case runs, same table
    assert again.summary["computed"] == 0 and again.summary["cases_per_second"] is None
    pd.testing.assert_frame_equal(comparable(again.table), comparable(result.table))
    assert len(Path(log).read_text().split()) == 7


def test_the_case_seed_follows_the_case_not_its_position():
    one = Campaign.of_function("f", counted, [{"x": 1}, {"x": 2}], seed=5).cases()
    two = Campaign.of_function("f", counted, [{"x": 2}, {"x": 1}], seed=5).cases()
    assert (one[0].seed, one[0].id) == (two[1].seed, two[1].id) and one[0].seed != one[1].seed
    assert Campaign.of_function("f", counted, [{"x": 1}], seed=6).cases()[0].seed != one[0].seed


def test_campaign_cli_json_and_bundled_specs(tmp_path, capsys):
    spec = tmp_path / "tiny.toml"
    spec.write_text('name = "tiny"\nkind = "design"\n[design]\nspeeds = 4\nreference = false\n'
                    '[design.grid]\nm = [0.25, 0.35]\n')
    assert main(["campaign", str(spec), "--workers", "1", "--out", str(tmp_path / "out"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert {"cases", "succeeded", "failed", "success_rate", "wall_time", "cases_per_second"} <= set(summary)
    assert (summary["cases"], summary["succeeded"], summary["success_rate"]) == (2, 2, 1.0)
    assert {"robustness", "design"} <= set(__import__("rollbot_oc.campaign", fromlist=["x"]).bundled_campaigns())
    assert len(load_campaign_spec("robustness").cases()) >= 200  # 100 courses, NMPC and PID
    design = load_campaign_spec("design")
    assert set(design.kind.axes) == {"phi_deg", "m"}


@pytest.mark.parametrize("change, message", [
    ({"kind": "sweep"}, "key 'kind' = 'sweep'; valid are"),
    ({"seed": -1}, "key 'seed' = -1 is out of range"),
    ({"extra": 1}, "unknown key(s) extra"),
    ({"design": {"grid": {"phi_deg": [45.0, 95.0]}}}, "phi"),
    ({"design": {"grid": {"wheels": [1.0]}}}, "unknown key 'wheels'"),
    ({"design": {"grid": {"m": {"from": 0.2, "to": 0.4, "steps": 0}}}}, "key 'steps' = 0 is out of range"),
    ({"design": {"speeds": 1, "grid": {"m": [0.3]}}}, "key 'speeds' = 1 is out of range"),
])
def test_bad_specs_are_refused_on_load_naming_file_and_key(change, message, tmp_path, capsys):
    with pytest.raises(ConfigError, match="tiny.toml") as caught:
        campaign_from_dict({**DESIGN, **change}, "tiny.toml")
    assert message in str(caught.value)
    spec = tmp_path / "bad.toml"
    spec.write_text('name = "bad"\nkind = "closed_loop"\n[closed_loop]\ncontrollers = ["pid", "lqr"]\n')
    assert main(["campaign", str(spec), "--workers", "1", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "bad.toml [closed_loop]: key 'controllers'" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_bad_workers_and_scheduler_are_refused_before_anything_runs(tmp_path, capsys, monkeypatch):
    spec = tmp_path / "tiny.toml"
    spec.write_text('name = "tiny"\nkind = "design"\n[design.grid]\nm = [0.3]\n')
    for argv, message in ((["--workers", "0"], "--workers 0 is out of range"),
                          (["--workers", "2", "--scheduler", "tcp://h:8786"], "give one"),
                          (["--scheduler", "nowhere"], "must be an address")):
        assert main(["campaign", str(spec), "--out", str(tmp_path / "out"), *argv]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_design_points_with_the_n_shape_bound_and_the_pareto_front(tmp_path, monkeypatch):
    """The bound's optimal-control call replaced by a stand-in (the real one takes seconds per design): heavier
    pendulums plan "faster" here, and one design's planning fails, which fails its row but keeps its measures."""
    import rollbot_oc.scenarios.bounds as bounds
    from rollbot_oc.core.errors import NotConverged

    def legs(params, start, stops):
        if params.m > 0.4:
            raise NotConverged("rest-to-rest plan to [1.2, 0.0]", "Maximum_Iterations_Exceeded")
        return [1.0 / params.m] * len(stops)

    monkeypatch.setattr(bounds, "_plan_legs", legs)
    spec = {"name": "bounded", "kind": "design",
            "design": {"speeds": 5, "n_shape_bound": True, "grid": {"m": [0.2, 0.3, 0.45]}}}
    result = run_campaign(campaign_from_dict(spec, "bounded.toml"), tmp_path, workers=1)
    table = result.table
    assert table["n_shape_bound"].tolist()[:3] == pytest.approx([4 / 0.306, 4 / 0.2, 4 / 0.3])
    assert table["n_shape_legs"].tolist()[1] == pytest.approx([5.0] * 4)
    last = table.iloc[3]
    assert last["status"] == "failed" and "Maximum_Iterations_Exceeded" in last["error"]
    assert last["tau_max"] > 0 and math.isnan(last["n_shape_bound"])
    front = result.summary["design"]["pareto_front"]  # lighter: wider range and shorter recovery, slower here
    assert {row["m"] for row in front} == {0.2, 0.3, 0.306}
    assert result.summary["design"]["trends"]["tau_max"]["m"].startswith("up 2, down 0")


def test_a_case_the_cluster_lost_is_an_error_row_and_runs_again(tmp_path, monkeypatch):
    """A worker that dies (here: its case reported lost, as ``as_completed`` reports a ``KilledWorker``) gives
    the case a ``worker failure`` row in the table and the summary, not a traceback; the next start runs only it."""
    from rollbot_oc.campaign import execution

    campaign = Campaign.of_function("counted", counted, [{"x": x, "log": str(tmp_path / "calls.log"),
                                                          "stop_at": -1} for x in range(3)])
    honest_run = execution._InProcess.run

    def losing_run(self, cases):
        for case in cases:
            if case.inputs["x"] == 1:
                yield execution.lost_row(case, RuntimeError("worker 127.0.0.1:4000 died"))
            else:
                yield from honest_run(self, [case])

    monkeypatch.setattr(execution._InProcess, "run", losing_run)
    lost = run_campaign(campaign, tmp_path / "out", workers=1, figures=False)
    assert lost.table["status"].tolist() == ["succeeded", "error", "succeeded"]
    assert lost.table["error"].tolist()[1] == "worker failure: RuntimeError: worker 127.0.0.1:4000 died"
    assert (lost.summary["succeeded"], lost.summary["errors"]) == (2, 1)
    monkeypatch.setattr(execution._InProcess, "run", honest_run)
    again = run_campaign(campaign, tmp_path / "out", workers=1, figures=False)
    assert (again.summary["computed"], again.summary["resumed"]) == (1, 2)
    assert again.table["double"].tolist() == [0, 2, 4]
    assert (tmp_path / "calls.log").read_text().split() == ["0", "2", "1"]


def test_time_ratios_to_the_bound_and_to_the_bound_plus_the_dwell():
    """A run's time over its course's bound, and over the bound plus the stop rule's rest at every stop: 15 s on
    a course bounded by 10 s with four stops of 0.5 s is 1.5 and 15 / 12 = 1.25; a course without a bound, and
    bound rows written before the dwell was recorded, give NaN."""
    from rollbot_oc.campaign.closed_loop import BOUND, ClosedLoopKind, time_ratios

    table = pd.DataFrame([
        {"course": 0, "controller": BOUND, "status": "succeeded", "completion_time": 10.0, "dwell": 2.0,
         "stop_errors": None},
        {"course": 0, "controller": "nmpc", "status": "succeeded", "completion_time": 15.0, "dwell": None,
         "stop_errors": [0.01, 0.02]},
        {"course": 1, "controller": BOUND, "status": "failed", "completion_time": None, "dwell": None,
         "stop_errors": None},
        {"course": 1, "controller": "nmpc", "status": "succeeded", "completion_time": 20.0, "dwell": None,
         "stop_errors": [0.03]},
    ])
    ratio, with_dwell = time_ratios(table), time_ratios(table, dwell=True)
    assert ratio[1] == pytest.approx(1.5) and with_dwell[1] == pytest.approx(1.25)
    assert math.isnan(ratio[0]) and math.isnan(ratio[3]) and math.isnan(with_dwell[3])  # bound row; no bound
    assert math.isnan(time_ratios(table.drop(columns="dwell"), dwell=True)[1])  # not recorded: not guessed
    summary = ClosedLoopKind(controllers=("nmpc", BOUND)).summarise(table)["controllers"]["nmpc"]
    assert summary["time_ratio_median"] == pytest.approx(1.5) and summary["time_ratio_dwell_median"] == pytest.approx(1.25)
