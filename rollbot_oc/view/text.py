"""What a person reads: values with units and sensible rounding, aligned tables, and the line that leads.

Every command's output without ``--json`` starts with one line that answers
"did it work, and how well" (completed or not, the completion time, the worst
stop error or deviation, the fallbacks), followed by the details.  The same
vocabulary serves the comparison table and the figures' titles, so that a
number reads the same everywhere:

* errors and deviations in cm, times in s, solve times in ms, lengths in m,
  angles in degrees; a missing value is ``-``;
* ``Field``: a value's key in a record, its label, unit and format;
  ``RUN_FIELDS`` are the comparison table's rows (``comparison_row``);
* ``run_verdict``/``run_headline``: a closed-loop run in one line;
* ``*_text``: each command's human output, made from the records it prints
  with ``--json`` (SI units), so that the two cannot disagree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MISSING", "number", "text_table", "Field", "RUN_FIELDS", "comparison_row", "comparison_table",
           "run_verdict", "run_headline", "run_title", "run_text", "compare_headline", "compare_text", "open_loop_text",
           "quasi_text", "stability_text", "problems_text", "params_text", "saved_run_verdict", "demo_text"]

MISSING = "-"


def _missing(value) -> bool:
    return value is None or (isinstance(value, float) and not math.isfinite(value))


def number(value, fmt: str = ".3g", unit: str = "", scale: float = 1.0) -> str:
    """``value * scale`` formatted with ``fmt``, then ``unit``; ``-`` for a missing value (None, NaN)."""
    if _missing(value):
        return MISSING
    text = format(value * scale, fmt)
    return f"{text} {unit}" if unit else text


def _cell(value, fmt: str = "") -> str:
    """A value for a table cell: yes/no for booleans, ``-`` when missing, numbers formatted with ``fmt``."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if _missing(value):
        return MISSING
    if isinstance(value, str) or not fmt:
        return str(value)
    return format(value, fmt)


def _numeric(cell: str) -> bool:
    try:
        float(cell.split()[0])
    except (ValueError, IndexError):
        return cell in (MISSING, "yes", "no")
    return True


def text_table(header: list[str], rows: list[list[str]], indent: str = "") -> str:
    """Plain-text columns under ``header``: numbers right-aligned (so that they line up), text left-aligned."""
    columns = list(zip(header, *rows))
    widths = [max(len(str(c)) for c in column) for column in columns]
    right = [all(_numeric(str(c)) for c in column[1:]) and len(column) > 1 for column in columns]
    lines = []
    for row in [header, *rows]:
        cells = [f"{str(c):>{w}}" if r else f"{str(c):<{w}}" for c, w, r in zip(row, widths, right)]
        lines.append(indent + "  ".join(cells).rstrip())
    return "\n".join(lines)


@dataclass(frozen=True)
class Field:
    """A value of a record, as people read it.

    Attributes
    ----------
    key : str
        Its key in the record.
    label : str
        What it is (``"completion time"``).
    unit : str
        Its unit in the record (``"cm"``); empty for none.
    fmt : str
        Format of a number (``".1f"``); empty: as it is.
    """

    key: str
    label: str
    unit: str = ""
    fmt: str = ""

    @property
    def heading(self) -> str:
        """The label with its unit, for a column or row heading: ``completion time (s)``."""
        return f"{self.label} ({self.unit})" if self.unit else self.label

    def cell(self, record: dict) -> str:
        """The value alone (``-`` if missing)."""
        return _cell(record.get(self.key), self.fmt)

    def text(self, record: dict) -> str:
        """The value and its unit: ``27.3 s``."""
        cell = self.cell(record)
        return f"{cell} {self.unit}" if self.unit and cell != MISSING else cell


def _field_lines(record: dict, fields, indent: str = "  ") -> list[str]:
    """``label  value unit``, aligned, for the fields ``record`` has a value for."""
    shown = [(f.label, f.text(record)) for f in fields if f.cell(record) != MISSING]
    width = max((len(label) for label, _ in shown), default=0)
    return [f"{indent}{label:<{width}}  {text}" for label, text in shown]


# -- closed-loop runs -----------------------------------------------------------------------------------------
RUN_FIELDS = (
    Field("completed", "completed"),
    Field("completion_time", "completion time", "s", ".1f"),
    Field("avg_speed", "average speed", "m/s", ".3f"),
    Field("max_stop_error", "largest stop error", "cm", ".1f"),
    Field("max_estimation_error_cm", "largest estimation error at a stop", "cm", ".1f"),
    Field("avg_deviation_cm", "average deviation", "cm", ".2f"),
    Field("max_deviation_cm", "largest deviation", "cm", ".2f"),
    Field("max_motor_torque", "largest motor torque", "N m", ".3f"),
    Field("min_normal_force", "least normal force", "N", ".2f"),
    Field("min_slide_margin", "least slide margin", "N", ".2f"),
    Field("solve_median_ms", "solve time median", "ms", ".2f"),
    Field("solve_p95_ms", "solve time p95", "ms", ".2f"),
    Field("fallbacks", "fallbacks (shifted / brake / PID)"),
    Field("ocp_bound", "minimum-time bound", "s", ".1f"),
    Field("bound_ratio", "time / minimum-time bound", "", ".2f"),
)

# A run's details after its headline: how far it got first, then RUN_FIELDS, then the run itself.
_DETAIL_FIELDS = (
    Field("stops", "stops reached"),
    Field("stop_errors_cm", "stop errors", "cm"),
    Field("reach_time", "on the circle after", "s", ".1f"),
    *RUN_FIELDS[1:],
    Field("max_driving_speed", "largest driving speed", "rad/s", ".2f"),
    Field("events", "contact events"),
    Field("duration", "simulated", "s", ".1f"),
    Field("wall_time", "wall time", "s", ".1f"),
)


def _cm(value):
    return None if value is None else 100 * value


def comparison_row(run) -> dict:
    """The comparison-table entries of one run (a ``scenarios.problem.RunResult``), keys of ``RUN_FIELDS``.

    Errors and deviations in cm, solve times in ms (the PID's controller time
    per step), the rest in SI units.
    """
    m = run.metrics
    row = {"controller": run.controller, "completed": m["completed"], "completion_time": m["completion_time"],
           "avg_speed": m["avg_speed"],
           "max_stop_error": 100 * max(m["stop_errors"]) if m["stop_errors"] else None,
           "avg_deviation_cm": _cm(m["avg_deviation"]), "max_deviation_cm": _cm(m["max_deviation"]),
           "max_motor_torque": m["max_motor_torque"], "min_normal_force": m["min_normal_force"],
           "min_slide_margin": m["min_slide_margin"]}
    if m.get("max_estimation_error") is not None:  # onboard sensing
        row["max_estimation_error_cm"] = 100 * m["max_estimation_error"]
    if "solve_time_median" in m:  # an optimising controller: its solves, fallbacks and plans
        row.update(solve_median_ms=1e3 * m["solve_time_median"], solve_p95_ms=1e3 * m["solve_time_p95"],
                   fallbacks=f"{m['fallback_shifted']} / {m.get('fallback_brake', 0)} / {m['fallback_pid']}")
        fastest = [plan.get("fastest") for plan in m.get("plans", [])]
        if fastest and all(f is not None for f in fastest):
            row["ocp_bound"] = float(sum(fastest))
            if m["completion_time"]:
                row["bound_ratio"] = m["completion_time"] / row["ocp_bound"]
    else:
        row.update(solve_median_ms=1e3 * m["step_time_median"], solve_p95_ms=1e3 * m["step_time_p95"])
    return row


def comparison_table(runs) -> str:
    """A Markdown table of ``comparison_row`` for each run (rows with no value at all left out)."""
    rows = [comparison_row(run) for run in runs]
    lines = ["| | " + " | ".join(r["controller"] for r in rows) + " |", "|---|" + "---|" * len(rows)]
    for field in RUN_FIELDS:
        cells = [field.cell(r) for r in rows]
        if any(c != MISSING for c in cells):
            lines.append(f"| {field.heading} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _stops_total(run) -> int | None:
    return len(run.problem.mission.stops) or None


def _events(events: list) -> str:
    names = {"jump": "lost contact", "slide": "slid"}
    return ", ".join(f"{names.get(e['kind'], e['kind'])} at {e['time']:.1f} s" for e in events) or "none"


def run_verdict(run) -> str:
    """A closed-loop run (``scenarios.problem.RunResult``) in a few words: did it work, and how well.

    Completed or not and when, the worst stop error or the deviations from the
    circle, contact events and exceeded limits, and the NMPC's fallbacks.
    """
    m = run.metrics
    parts = run.problem.mission.verdict(m)  # each kind says how its run went
    if m["events"]:
        parts.append(_events(m["events"]))
    parts += [f"{what} limit exceeded" for what in ("torque", "speed") if m.get(f"{what}_limit_violation")]
    if "fallback_shifted" in m:
        shifted, pid = m["fallback_shifted"], m["fallback_pid"]
        brake = m.get("fallback_brake", 0)
        named = [f"{n} {what}" for n, what in ((shifted, "shifted plan"), (brake, "brake"), (pid, "PID")) if n]
        parts.append(f"fallbacks: {', '.join(named)}" if named else "no fallbacks")
    return ", ".join(p for p in parts if p)


def run_headline(run) -> str:
    """``problem, controller (seed N): verdict`` (see ``run_verdict``)."""
    return f"{run.problem.name}, {run.controller} (seed {run.seed}): {run_verdict(run)}"


def run_title(run) -> str:
    """A figure's title for a run: the problem and controller, then the verdict on a second line."""
    return f"{run.problem.name}, {run.controller} (seed {run.seed})\n{run_verdict(run)}"


def run_text(run) -> str:
    """The output of ``rollbot-oc run``: the headline, then the details with units."""
    m = run.metrics
    record = dict(comparison_row(run), reach_time=m.get("reach_time"), max_driving_speed=m["max_driving_speed"],
                  events=_events(m["events"]), duration=m["duration"], wall_time=m.get("wall_time"))
    total = _stops_total(run)
    if total is not None:
        record["stops"] = f"{len(m['stop_errors'])} of {total}"
        if m["stop_errors"]:
            record["stop_errors_cm"] = ", ".join(f"{100 * e:.1f}" for e in m["stop_errors"])
    return "\n".join([run_headline(run), *_field_lines(record, _DETAIL_FIELDS)])


def compare_headline(runs) -> str:
    """Which controller did better on the problem of ``runs`` (two runs that completed), else how many completed."""
    name = runs[0].problem.name
    if len(runs) != 2 or not all(r.metrics["completed"] for r in runs):
        done = [r.controller for r in runs if r.metrics["completed"]]
        return f"{name}: completed by {', '.join(done) or 'none'} of {', '.join(r.controller for r in runs)}"
    (a, b), (ma, mb) = runs, (runs[0].metrics, runs[1].metrics)
    if _stops_total(a) is not None:
        return (f"{name}: {b.controller} {ma['completion_time'] / mb['completion_time']:.1f}x as fast as "
                f"{a.controller} ({number(mb['completion_time'], '.1f', 's')} against "
                f"{number(ma['completion_time'], '.1f', 's')})")
    return (f"{name}: average deviation {b.controller} {number(mb['avg_deviation'], '.2f', 'cm', 100)}, "
            f"{a.controller} {number(ma['avg_deviation'], '.2f', 'cm', 100)}")


def compare_text(runs) -> str:
    """The output of ``rollbot-oc compare``: which controller did better, each run's verdict, then the table."""
    lines = [compare_headline(runs)] + [f"  {run.controller}: {run_verdict(run)}" for run in runs]
    return "\n".join(lines + ["", comparison_table(runs)])


# -- open loop, analysis, listings ----------------------------------------------------------------------------
def open_loop_text(rows: list[dict], name: str | None = None) -> str:
    """Open-loop measurements (``openloop`` rows; with the theory's values for a problem's ``run_open_loop``)."""
    settled = [r for r in rows if r["settled"]]
    theory = any("R0_theory" in r for r in rows)
    head = f"{name}: " if name else ""
    head += f"{len(settled)} of {len(rows)} driving speeds settled on a circle"
    errors = [abs(r["R0_error"]) for r in rows if r.get("R0_error") is not None]
    if errors:
        head += f", measured R0 within {number(max(errors), '.2g', '%', 100)} of the theory"
    elif settled:
        radii = [r["R0"] for r in settled]
        head += f", R0 from {min(radii):.3f} to {max(radii):.3f} m"
    header = ["omega0 (rad/s)", "R0 (m)"] + (["theory (m)", "error (%)"] if theory else []) + [
        "Omega (rad/s)", "xi (deg)", "drift (mm/s)", "settled"]
    table = []
    for r in rows:
        cells = [number(r["omega0"], ".3f"), number(r["R0"], ".4f")]
        if theory:
            cells += [number(r.get("R0_theory"), ".4f"), number(r.get("R0_error"), ".2g", scale=100)]
        cells += [number(r["Omega"], ".4f"), number(r["xi"], ".2f", scale=180 / math.pi),
                  number(r.get("drift"), ".1f", scale=1e3), _cell(r["settled"])]
        table.append(cells)
    lines = [head, text_table(header, table, "  ")]
    lines += [f"  omega0 {r['omega0']:g} rad/s: {r['error']}" for r in rows if r.get("error")]
    return "\n".join(lines)


def quasi_text(rows: list[dict], branch: str) -> str:
    """Quasi-stable states (``quasi`` rows): how many were found and their radii, then the table."""
    found = [r for r in rows if r["converged"]]
    head = f"{len(found)} of {len(rows)} quasi-stable states found ({branch} branch)"
    if found:
        radii = [abs(r["R0"]) for r in found]
        head += f": R0 from {min(radii):.3f} to {max(radii):.3f} m" if len(found) > 1 else f": R0 = {radii[0]:.3f} m"
    header = ["omega0 (rad/s)", "R0 (m)", "Omega (rad/s)", "theta0 (deg)", "xi (deg)", "speed (m/s)",
              "torque (N m)", "found"]
    deg = 180 / math.pi
    table = [[number(r["omega0"], ".3f")] + ([number(r["R0"], ".4f"), number(r["Omega"], ".4f"),
                                              number(r["theta0"], ".2f", scale=deg), number(r["xi"], ".2f", scale=deg),
                                              number(r.get("speed"), ".3f"), number(r.get("motor_torque"), ".3f")]
                                             if r["converged"] else [MISSING] * 6) + [_cell(r["converged"])]
             for r in rows]
    return "\n".join([head, text_table(header, table, "  ")])


def stability_text(rows: list[dict], branch: str) -> str:
    """Linearised stability (``stability`` rows): stable or not and the recovery times, then the table."""
    found = [r for r in rows if r["converged"]]
    stable = [r for r in found if r["stable"]]
    head = f"stable at {len(stable)} of {len(rows)} driving speeds ({branch} branch)"
    taus = [r["tau"] for r in stable if r["tau"] is not None]
    if taus:
        head += f": recovery time {min(taus):.1f} to {max(taus):.1f} s"
    header = ["omega0 (rad/s)", "Re(lambda2) (1/s)", "Im(lambda2) (1/s)", "recovery time (s)", "stable"]
    table = [[number(r["omega0"], ".3f")] + ([number(r["lambda2"][0], ".4f"), number(r["lambda2"][1], ".4f"),
                                              number(r["tau"], ".2f")] if r["converged"] else [MISSING] * 3)
             + [_cell(r["stable"]) if r["converged"] else "no state"] for r in rows]
    return "\n".join([head, text_table(header, table, "  ")])


def problems_text(rows: list[dict]) -> str:
    """The bundled scenarios."""
    table = [[r["name"], r["kind"], r["description"]] for r in rows]
    widths = [max(len(r[i]) for r in table) for i in range(2)]
    lines = [f"{len(rows)} bundled scenarios (run one with 'rollbot-oc run NAME'):"]
    lines += [f"  {n:<{widths[0]}}  {k:<{widths[1]}}  {d}" for n, k, d in table]
    return "\n".join(lines)


def params_text(record: dict) -> str:
    """A robot (the ``params`` command's record): its steering range and recovery, the parameters, the derived values.

    Every value is shown with its unit and where it came from: default, file or derived.
    """
    derived = {d["key"]: d["value"] for d in record["derived"]}
    head = f"{record['robot']}: "
    if derived["R0_min"] is None:
        head += record["derived"][-1]["note"]
    else:
        top = (f"{number(derived['R0_max'], '.3f', 'm')}" if derived["R0_max"] is not None else
               f"the end of the slow branch at {number(derived['reach'], '.2f', 'rad/s')}")
        head += (f"revolves on circles of {number(derived['R0_min'], '.3f', 'm')} to {top}, worst recovery time "
                 f"{number(derived['tau_max'], '.1f', 's')}, "
                 + ("stable" if derived["stable"] else "NOT stable") + " at every driving speed")
    header = ["value", "unit", "source", "meaning"]
    rows = [[p["key"], number(p["value"], ".4g"), p["unit"], p["source"], p["meaning"]] for p in record["params"]]
    derived_rows = [[d["key"], _cell(d["value"], ".4g"), d["unit"], d["source"], d["meaning"]]
                    for d in record["derived"]]
    return "\n".join([head, text_table(["parameter", *header], rows, "  "), "",
                      text_table(["derived value", *header], derived_rows, "  ")])


def saved_run_verdict(result) -> str:
    """A saved run (``SimulationResult``) in a few words: how long, how fast, contact events."""
    events = _events([{"kind": e.kind, "time": e.time} for e in result.events])
    return (f"{result.t[-1]:.1f} s simulated, driving speed up to {abs(result.driving_speed).max():.2f} rad/s, "
            f"contact events: {events}")


def demo_text(summary: dict, report) -> str:
    """The ``demo`` command's output: where the report is and its key numbers (``make_report``'s summary)."""
    n, q = summary["n_shape"], summary["quasi_stable"]
    speed_up = f" ({n['speed_up']:.1f}x as fast)" if n["speed_up"] else ""
    worst = {c: number(max(n[f"{c}_stop_errors"]), ".1f", "cm", 100) if n[f"{c}_stop_errors"] else MISSING
             for c in ("pid", "nmpc")}
    return "\n".join([
        f"report written: {report} ({summary['wall_time']:.0f} s)",
        f"  N-shape: PID {number(n['pid_time'], '.1f', 's')}, NMPC {number(n['nmpc_time'], '.1f', 's')}{speed_up}; "
        f"worst stop error PID {worst['pid']}, NMPC {worst['nmpc']}",
        f"  NMPC solve time: median {number(n['nmpc_solve_time_median'], '.2f', 'ms', 1e3)}, "
        f"p95 {number(n['nmpc_solve_time_p95'], '.2f', 'ms', 1e3)}",
        f"  quasi-stable radius {q['R0_at_rest']:.3f} to {q['R0_at_max_speed']:.3f} m, recovery time "
        f"{q['tau_range'][0]:.1f} to {q['tau_range'][1]:.1f} s",
        f"  open loop: simulated R0 within {number(summary['open_loop_max_R0_error'], '.2g', '%', 100)} of the theory",
    ])
