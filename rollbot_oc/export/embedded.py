"""The embedded controller in Python: the exported control step evaluated by CasADi, as a ``Controller``.

``EmbeddedController`` is what the C export runs, step for step: each period it looks up the reference
window of the current solve instant (``EmbeddedReference.window``) and evaluates the one control-step
Function (``export.step``) on its memory, the measurement and that window.  ``record`` keeps every
measurement and command (the log the C project replays).  ``export.library.CController`` runs the same
controller through the exported C library.
"""

from __future__ import annotations

import numpy as np

from rollbot_oc.export.reference import EmbeddedReference
from rollbot_oc.export.step import STATUS, StepFunction
from rollbot_oc.core.fastcall import FastFunction
from rollbot_oc.control.protocol import Command, ControllerBase, Observation

__all__ = ["EmbeddedController", "EmbeddedBase"]


class EmbeddedBase(ControllerBase):
    """What the Python and the C embedded controllers share: the log, ``done`` and the report.

    Parameters
    ----------
    step : StepFunction
    reference : EmbeddedReference
    record : bool
        Keep every measurement (12,: time and full state) and command (``log``).
    """

    def __init__(self, step: StepFunction, reference: EmbeddedReference, record: bool = False):
        self.step, self.reference, self.record = step, reference, record
        self.reset()

    def reset(self):
        self.measurements, self.commands, self.statuses = [], [], []
        self._done = False

    def _log(self, meas: np.ndarray, accel: float, status: int):
        if self.record:
            self.measurements.append(meas.copy())
            self.commands.append(accel)
        self.statuses.append(status)
        self._done = status == 4

    @property
    def done(self) -> bool:
        """True ``finish_hold`` seconds after the last stop was reached (status ``done``)."""
        return self._done

    def report(self) -> dict:
        """Counts of every step status (``step.STATUS``) and the reference's legs."""
        counts = np.bincount(np.asarray(self.statuses, int), minlength=len(STATUS))
        legs = self.reference.legs if self.reference is not None else []
        return {"solver": "embedded RTI (qrqp)", "statuses": {STATUS[i]: int(c) for i, c in enumerate(counts)},
                "solves": int(counts[0] + counts[2]), "failed_solves": int(counts[2]), "legs": legs,
                "plan_duration": float(sum(leg["duration"] for leg in legs))}

    @staticmethod
    def measurement(obs: Observation) -> np.ndarray:
        """The step's ``meas`` input (12,): the time, s, and the measured full state."""
        return np.concatenate([[obs.t], obs.state])


class EmbeddedController(EmbeddedBase):
    """The exported control step evaluated in CasADi's virtual machine (module doc)."""

    def __init__(self, step: StepFunction, reference: EmbeddedReference, record: bool = False):
        self._fun = FastFunction(step.function)
        super().__init__(step, reference, record)

    def reset(self):
        super().reset()
        self.mem = self.step.initial_memory.copy()

    def __call__(self, obs: Observation) -> Command:
        meas = self.measurement(obs)
        mem, layout = self.mem, self.step.memory
        k, leg, leg_k = (int(mem[layout[name]][0]) for name in ("k", "segment", "segment_k"))
        ref = self.reference.window(leg, (k - leg_k) // self.step.every, self.step.N)
        accel, mem, status = self._fun(self.mem, meas, ref)
        self.mem = mem.copy()
        accel, status = float(accel[0]), int(status[0])
        self._log(meas, accel, status)
        return Command(accel=accel)
