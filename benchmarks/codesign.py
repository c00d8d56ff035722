"""Hardware co-design: the fastest N-shape within manufacturable bounds, recovering within 8 s, steering as widely.

Find ``phi``, ``m`` and ``r0`` that minimise the minimum-time N-shape bound
(``rollbot_oc.scenarios.bounds.n_shape_bound``: the bundled N-shape on a level floor)
subject to

* a worst recovery time ``tau_max`` of at most 8 s at every driving speed
  (60 speeds over [0, 3 pi] rad/s), and
* a radius range ``R0_max - R0_min`` at least the prototype's,

within the manufacturable bounds ``BOUNDS``: the arm's angle 30 to 60 deg,
the pendulum (with motor and battery) 0.2 to 0.45 kg, its radius 0.07 to
0.10 m inside the 0.12 m shell (at least 2 cm for the mass); the motor's
torque limit follows the paper's ``r0 m g``, everything else is the
prototype's.

Method: derivative-free, over campaigns (``DesignKind`` cases with the bound
switched on), because the bound is rugged: small changes of a parameter move
it both ways and by more than the trends between designs (each leg's plan is
a local optimum of IPOPT, and a leg's end heading changes the next leg), so
finite differences, and the OCP's parametric sensitivities that they would
approximate, describe one local optimum, not the design's trend (stage 0
below measures this; the figures are in the README).  The constraints are cheap and checked first, so only
feasible designs pay for an OCP.

0. the prototype and its six neighbours at +-1 deg, +-0.01 kg, +-0.002 m;
1. a coarse grid (4 x 4 x 2: ``phi`` 35, 45, 55, 60 deg, ``m`` 0.2, 0.3, 0.4,
   0.45 kg, ``r0`` 0.075, 0.09 m), feasible points only (a heavy pendulum
   keeps the prototype's radius range only with a large ``phi``);
2. compass search from the best: the six neighbours at the current step
   (5 deg, 0.05 kg, 0.01 m), move to the best improvement, else halve the
   step (once: the search ends at 2.5 deg, 0.025 kg, 0.005 m);
3. the best design's six neighbours, as for the prototype: the median of a
   neighbourhood says whether a gain is the design's or a lucky plan.

Every evaluation is a campaign case in ``--out`` (default
``out/codesign``): a run that stops carries on, and a point asked for twice
is computed once.  The result (every evaluation, the best design, its gain)
is written to ``--result`` (default ``benchmarks/codesign_result.json``).
``--nmpc`` also runs the NMPC on the N-shape with the best design (the
closed-loop check; not run for the committed result).

Run: .venv/bin/python benchmarks/codesign.py [--workers N] [--out DIR] [--result FILE] [--nmpc]
"""

import argparse
import math
import time
from pathlib import Path

import numpy as np

from rollbot_oc.campaign import Campaign, run_campaign
from rollbot_oc.campaign.design_points import DesignKind
from rollbot_oc.core.outputs import write_json
from rollbot_oc.model.params import RollbotParams

BOUNDS = {"phi_deg": (30.0, 60.0), "m": (0.2, 0.45), "r0": (0.07, 0.10)}
STEP = {"phi_deg": 5.0, "m": 0.05, "r0": 0.01}  # the compass search's first step
NEIGHBOUR = {"phi_deg": 1.0, "m": 0.01, "r0": 0.002}  # the neighbourhood of a design (stages 0 and 3)
TAU_LIMIT = 8.0  # s
SPEEDS = 60
PROTOTYPE = RollbotParams()


def point(phi_deg, m, r0) -> dict:
    """A design as campaign inputs (rounded, so that the same design is always the same case)."""
    return {"phi_deg": round(float(phi_deg), 6), "m": round(float(m), 6), "r0": round(float(r0), 6)}


def inside(p: dict) -> bool:
    return all(BOUNDS[k][0] - 1e-12 <= p[k] <= BOUNDS[k][1] + 1e-12 for k in BOUNDS)


class Evaluator:
    """Constraints (cheap, in this process) and bounds (campaigns) of designs, remembered."""

    def __init__(self, out: Path, workers):
        self.out, self.workers = out, workers
        self.rows = {}  # key -> row
        self.calls = 0
        self.range_min = None

    @staticmethod
    def key(p):
        return (p["phi_deg"], p["m"], p["r0"])

    def _campaign(self, name, points, bound):
        kind = DesignKind(PROTOTYPE, points, SPEEDS, n_shape_bound=bound, reference=False)
        return run_campaign(Campaign(name, kind), self.out / name, workers=self.workers if bound else 1,
                            figures=False).table

    def feasible(self, points):
        """The points within the bounds that meet the constraints (one cheap campaign)."""
        points = [p for p in points if inside(p)]
        if not points:
            return []
        table = self._campaign("constraints", points, False)
        ok = (table["status"] == "succeeded") & (table["tau_max"] <= TAU_LIMIT) & \
            (table["radius_range"] >= self.range_min - 1e-12)
        return [p for p, good in zip(points, ok) if good]

    def bounds(self, points, stage):
        """Evaluate the N-shape bound of ``points`` (one campaign, in parallel); their rows."""
        new = [p for p in points if self.key(p) not in self.rows]
        if new:
            table = self._campaign("bounds", new, True)
            self.calls += len(new)
            for p, row in zip(new, table.to_dict("records")):
                self.rows[self.key(p)] = {**p, "stage": stage, "status": row["status"], "error": row["error"],
                                          "radius_range": row["radius_range"], "tau_max": row["tau_max"],
                                          "n_shape_bound": row["n_shape_bound"], "n_shape_legs": row["n_shape_legs"],
                                          "wall_time": row["wall_time"]}
        return [self.rows[self.key(p)] for p in points]


def value(row) -> float:
    """The objective of an evaluated design (inf if its bound could not be planned)."""
    bound = row["n_shape_bound"]
    return float(bound) if bound is not None and math.isfinite(bound) else math.inf


def neighbours(p: dict, steps: dict) -> list[dict]:
    """The six designs one step away from ``p`` along each parameter."""
    out = []
    for k in BOUNDS:
        for sign in (-1, 1):
            q = {key: p[key] for key in BOUNDS}
            q[k] = p[k] + sign * steps[k]
            out.append(point(**q))
    return out


def neighbourhood(evaluator, p, stage) -> dict:
    """The bound at ``p`` and at its six close neighbours (feasible or not: this measures how rugged the bound
    is there): median, min, max."""
    rows = evaluator.bounds([p] + [q for q in neighbours(p, NEIGHBOUR) if inside(q)], stage)
    values = np.array([value(r) for r in rows])
    finite = values[np.isfinite(values)]
    return {"design": p, "bound": value(rows[0]), "neighbours": len(rows) - 1,
            "median": float(np.median(finite)) if finite.size else None,
            "min": float(finite.min()) if finite.size else None, "max": float(finite.max()) if finite.size else None}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, help="local worker processes for the bounds (default: all cores)")
    parser.add_argument("--out", default="out/codesign", help="the campaigns' folder (kept: a rerun resumes)")
    parser.add_argument("--result", default=str(Path(__file__).with_name("codesign_result.json")))
    parser.add_argument("--nmpc", action="store_true", help="also run the NMPC on the N-shape with the best design")
    args = parser.parse_args()
    start = time.perf_counter()
    evaluator = Evaluator(Path(args.out), args.workers)
    prototype = point(math.degrees(PROTOTYPE.phi), PROTOTYPE.m, PROTOTYPE.r0)
    reference = evaluator._campaign("constraints", [prototype], False).iloc[0]
    evaluator.range_min = float(reference["radius_range"])
    print(f"prototype: radius range {evaluator.range_min:.4f} m, tau_max {reference['tau_max']:.3f} s", flush=True)

    around_prototype = neighbourhood(evaluator, prototype, "0 prototype neighbourhood")
    print("stage 0:", around_prototype, flush=True)

    grid = [point(a, b, c) for a in (35.0, 45.0, 55.0, 60.0) for b in (0.2, 0.3, 0.4, 0.45) for c in (0.075, 0.09)]
    rows = evaluator.bounds(evaluator.feasible(grid), "1 coarse grid")
    best = min(rows + [evaluator.rows[evaluator.key(prototype)]], key=value)
    print(f"stage 1: {len(rows)} feasible of {len(grid)}; best {best}", flush=True)

    steps, halvings = dict(STEP), 0
    while halvings <= 1:
        candidates = evaluator.feasible(neighbours(best, steps))
        rows = evaluator.bounds(candidates, f"2 compass step {steps['phi_deg']:g} deg")
        better = [r for r in rows if value(r) < value(best) - 1e-9]
        if better:
            best = min(better, key=value)
            print(f"stage 2: moved to {best}", flush=True)
        else:
            steps, halvings = {k: v / 2 for k, v in steps.items()}, halvings + 1
            print(f"stage 2: no better neighbour; step halved to {steps}", flush=True)
    best_point = point(best["phi_deg"], best["m"], best["r0"])
    around_best = neighbourhood(evaluator, best_point, "3 best neighbourhood")
    print("stage 3:", around_best, flush=True)

    proto_row = evaluator.rows[evaluator.key(prototype)]
    result = {
        "problem": "minimise the minimum-time N-shape bound (bundled n_shape, level floor) subject to tau_max <= "
                   f"{TAU_LIMIT} s at every speed ({SPEEDS} speeds) and a radius range >= the prototype's",
        "bounds": {k: list(v) for k, v in BOUNDS.items()},
        "method": "derivative-free over campaigns: coarse 4x4x2 grid of feasible designs, then compass search "
                  "with one step halving; neighbourhoods of +-1 deg, +-0.01 kg, +-0.002 m around prototype and best",
        "prototype": {**proto_row, "neighbourhood": around_prototype},
        "best": {**best, "neighbourhood": around_best},
        "gain": {"bound": value(proto_row) - value(best), "ratio": value(best) / value(proto_row),
                 "neighbourhood_median_ratio": (around_best["median"] / around_prototype["median"]
                                                if around_best["median"] and around_prototype["median"] else None)},
        "evaluations": sorted(evaluator.rows.values(), key=lambda r: r["stage"]),
        "bound_evaluations": len(evaluator.rows),
        "wall_time": time.perf_counter() - start,
    }
    if args.nmpc:  # the closed-loop check of the best design (the NMPC's own N-shape, on its 1 deg slope)
        from rollbot_oc.scenarios.problem import run_problem
        from rollbot_oc.scenarios.bundled import load_bundled

        params = PROTOTYPE.with_changes(phi=math.radians(best["phi_deg"]), m=best["m"], r0=best["r0"])
        result["nmpc_best"] = run_problem(load_bundled("n_shape", base=params), "nmpc").metrics
    write_json(args.result, result)
    print(f"best {best_point}: bound {value(best):.3f} s against the prototype's {value(proto_row):.3f} s "
          f"({100 * (1 - result['gain']['ratio']):.1f} % faster); neighbourhood medians "
          f"{around_best['median']} against {around_prototype['median']} s; {len(evaluator.rows)} bounds in "
          f"{result['wall_time']:.0f} s")


if __name__ == "__main__":
    main()
