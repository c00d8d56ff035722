"""Robustness on random courses: the controllers on at least 100 seeded courses, through the campaign engine.

The bundled ``robustness`` campaign (``problems/campaigns/robustness.toml``:
100 courses of ``rollbot_oc.scenarios.courses``, random robots, floors, sensors and
+-10 % model error, the NMPC, the PID baseline and each course's minimum-time
bound), with the number of courses and the controllers as options.  It
reports, per controller, the success rate, the stop errors, the completion
times and their ratio to each course's bound, and every failure with its
cause (the campaign's ``summary.md``), and keeps the campaign's folder
(``--out``), so that an interrupted run carries on where it stopped and a
run with more controllers reuses the rows already computed.

The NMPC plans each leg as the robot moves (four IPOPT starts per leg from rest, two per refinement) and
the bound is five starts per leg: the full campaign is meant for a cluster
(``--scheduler``) or a night; ``--controllers pid`` runs the baseline alone.

Run: .venv/bin/python benchmarks/bench_robustness.py [--courses 100] [--controllers nmpc pid bound]
     [--first 0] [--workers N | --scheduler ADDR] [--out out/bench_robustness] [--result FILE]
"""

import argparse
import shlex
import sys

from rollbot_oc.campaign import campaign_from_dict, run_campaign
from rollbot_oc.campaign.spec import bundled_campaign_table
from rollbot_oc.campaign.summary import summary_markdown
from rollbot_oc.core.outputs import atomic_write_text


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--courses", type=int, default=100, help="number of courses (default 100)")
    parser.add_argument("--first", type=int, default=0, help="index of the first course (default 0)")
    parser.add_argument("--controllers", nargs="+", default=["nmpc", "pid", "bound"],
                        help="nmpc, pid and/or bound (default: all three)")
    parser.add_argument("--workers", type=int, help="local worker processes (default: the machine's cores)")
    parser.add_argument("--scheduler", help="an existing Dask scheduler, tcp://HOST:8786")
    parser.add_argument("--out", default="out/bench_robustness", help="the campaign's folder (kept, resumable)")
    parser.add_argument("--result", help="also write the report to this file")
    args = parser.parse_args()
    spec = bundled_campaign_table("robustness")
    spec["closed_loop"].update(courses=args.courses, first_course=args.first, controllers=args.controllers)
    campaign = campaign_from_dict(spec, "bundled campaign robustness (benchmark options)")
    result = run_campaign(campaign, args.out, workers=args.workers, scheduler=args.scheduler)
    command = "benchmarks/bench_robustness.py " + shlex.join(sys.argv[1:])
    text = f"Command: {command}\nFolder: {result.folder}\n\n{summary_markdown(result.summary)}"
    print(text)
    if args.result:
        atomic_write_text(args.result, text)


if __name__ == "__main__":
    main()
