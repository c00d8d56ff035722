"""The summary of a finished campaign: counts, speed, every failure with its cause, the kind's figures.

``summarise`` gives a plain dict (``summary.json``): ``cases``,
``succeeded``, ``failed`` (every case that did not succeed), ``errors``
(those that raised), ``success_rate``, ``computed`` and ``resumed`` (cases
run now and found finished on disk), ``wall_time`` (s, this invocation,
cluster start included), ``startup_time`` (s, of which starting the cluster),
``cases_per_second`` (computed cases over ``wall_time``; null if none ran),
``case_time_median``/``_p95``/``_total`` (s per case, measured in the
workers), ``workers``, ``where``, ``code`` (fingerprints of the code that
computed the rows), ``failures`` (each: case, the inputs that name it,
status and cause)
and the kind's own summary under the kind's name.  ``summary_markdown``
renders it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["summarise", "summary_markdown", "quantiles"]


def quantiles(values, prefix: str) -> dict:
    """``{prefix}_median``, ``_p95`` and ``_max`` of the finite ``values`` (None if there are none)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], float)
    if not v.size:
        return {f"{prefix}_median": None, f"{prefix}_p95": None, f"{prefix}_max": None}
    return {f"{prefix}_median": float(np.median(v)), f"{prefix}_p95": float(np.percentile(v, 95)),
            f"{prefix}_max": float(v.max())}


def summarise(campaign, table, *, computed: int, resumed: int, wall_time: float, startup_time: float,
              workers: int, where: str) -> dict:
    """The summary of ``campaign``'s finished ``table`` (see the module doc)."""
    kind = campaign.kind
    status = table["status"]
    cases = len(table)
    succeeded = int((status == "succeeded").sum())
    given = list(dict.fromkeys(key for inputs in kind.case_inputs()[:1] for key in inputs))  # what names a case
    failures = [{"case": int(row["case"]), **{key: row[key] for key in given}, "status": row["status"],
                 "error": row["error"]} for _, row in table[status != "succeeded"].iterrows()]
    times = table["wall_time"].dropna().to_numpy(float)
    return {
        "campaign": campaign.name, "kind": kind.name, "description": campaign.description, "seed": campaign.seed,
        "source": campaign.source, "cases": cases, "succeeded": succeeded, "failed": cases - succeeded,
        "errors": int((status == "error").sum()), "success_rate": succeeded / cases if cases else None,
        "computed": computed, "resumed": resumed, "wall_time": wall_time, "startup_time": startup_time,
        "cases_per_second": computed / wall_time if computed and wall_time > 0 else None,
        "case_time_median": float(np.median(times)) if times.size else None,
        "case_time_p95": float(np.percentile(times, 95)) if times.size else None,
        "case_time_total": float(times.sum()), "workers": workers, "where": where,
        "code": sorted({c for c in table["code"].dropna()}), "failures": failures,
        kind.name: kind.summarise(table),
    }


def _cell(value) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value).replace("|", "\\|")


def _table(rows: list[dict]) -> list[str]:
    keys = list(dict.fromkeys(key for row in rows for key in row))
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    return lines + ["| " + " | ".join(_cell(row.get(key)) for key in keys) + " |" for row in rows]


def _section(title: str, value) -> list[str]:
    """Markdown of a summary entry: scalars as a list, dicts of dicts and lists of dicts as tables."""
    if isinstance(value, dict) and value and all(isinstance(v, dict) for v in value.values()):
        return [f"### {title}", ""] + _table([{"": key, **v} for key, v in value.items()]) + [""]
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        return [f"### {title}", ""] + _table(value) + [""]
    if isinstance(value, dict):
        lines = [f"### {title}", ""]
        for key, v in value.items():
            lines += _section(key, v) if isinstance(v, (dict, list)) and v and not _numbers(v) \
                else [f"* {key}: {_cell(v) if not isinstance(v, list) else ', '.join(map(_cell, v))}"]
        return lines + [""]
    return [f"* {title}: {_cell(value)}"]


def _numbers(value) -> bool:
    return isinstance(value, list) and all(not isinstance(v, (dict, list)) for v in value)


def summary_markdown(summary: dict) -> str:
    """``summary.md``: the counts, the speed, the kind's summary and every failure with its cause."""
    rate = summary["success_rate"]
    lines = [f"# Campaign {summary['campaign']} ({summary['kind']})", ""]
    if summary["description"]:
        lines += [summary["description"], ""]
    lines += [
        f"* cases: {summary['cases']}, succeeded {summary['succeeded']}, failed {summary['failed']} "
        f"(of which errors {summary['errors']}), success rate {_cell(None if rate is None else 100 * rate)} %",
        f"* this run: {summary['computed']} cases computed, {summary['resumed']} found finished, wall time "
        f"{summary['wall_time']:.1f} s (start-up {summary['startup_time']:.1f} s), "
        f"{_cell(summary['cases_per_second'])} cases/s, {summary['where']}",
        f"* time per case (in the workers): median {_cell(summary['case_time_median'])} s, p95 "
        f"{_cell(summary['case_time_p95'])} s, total {_cell(summary['case_time_total'])} s",
        f"* seed {summary['seed']}, spec {summary['source']}, code {', '.join(summary['code']) or '-'}", "",
    ]
    if len(summary["code"]) > 1:
        lines += ["**Warning**: the rows were computed by different versions of the code (resumed after a change).",
                  ""]
    kind = summary.get(summary["kind"]) or {}
    for key, value in kind.items():
        lines += _section(key.replace("_", " "), value)
    lines += ["## Failures", ""]
    lines += _table(summary["failures"]) if summary["failures"] else ["None."]
    return "\n".join(lines) + "\n"
