"""The closed loop through C: the exported controller's shared library driven by the simulator (ctypes).

``CController(folder)`` loads ``librollbot_controller.so`` of a folder written by ``export_c`` and built
(``project.build``), and is a ``Controller``: each period it passes the observation to ``rollbot_step``
(the C API of ``rollbot_controller.h``) and returns its motor acceleration.  The context the step works
in is one buffer of ``rollbot_context_bytes()`` bytes, allocated here once.
"""

from __future__ import annotations

import ctypes
import hashlib
from pathlib import Path

from rollbot_oc.core.errors import ConfigError
from rollbot_oc.export.embedded import EmbeddedBase
from rollbot_oc.control.protocol import Command, Observation

__all__ = ["CController", "LIBRARY"]

LIBRARY = "librollbot_controller.so"


class _Command(ctypes.Structure):
    _fields_ = [("accel", ctypes.c_double), ("status", ctypes.c_int)]


class CController(EmbeddedBase):
    """The exported C controller as a ``Controller`` (module doc).

    Parameters
    ----------
    folder : str or Path
        A built export (``librollbot_controller.so`` in it).
    step, reference : optional
        The ``StepFunction`` and ``EmbeddedReference`` it was exported from, for the report (``legs``).
    record : bool
        Keep every measurement and command (``log``).

    Raises
    ------
    ConfigError
        If the library is missing or does not load.
    """

    def __init__(self, folder, step=None, reference=None, record: bool = False):
        path = Path(folder) / LIBRARY
        try:
            self._lib = lib = ctypes.CDLL(str(path.resolve()))
        except OSError as exc:
            raise ConfigError(f"{path}: the exported controller's library does not load ({exc}); "
                              "build it with make") from None
        lib.rollbot_context_bytes.restype = ctypes.c_ulong
        lib.rollbot_init.argtypes = [ctypes.c_void_p]
        lib.rollbot_step.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_double), ctypes.POINTER(_Command)]
        self.context_bytes = int(lib.rollbot_context_bytes())
        self.library_sha256 = hashlib.sha256(path.read_bytes()).hexdigest()  # which build the run's JSON came from
        self._context = (ctypes.c_double * (self.context_bytes // 8 + 1))()  # 8-byte aligned
        self._meas = (ctypes.c_double * 12)()
        self._command = _Command()
        super().__init__(step, reference, record)

    def reset(self):
        super().reset()
        self._lib.rollbot_init(self._context)

    def __call__(self, obs: Observation) -> Command:
        meas = self.measurement(obs)
        self._meas[:] = meas.tolist()
        if self._lib.rollbot_step(self._context, self._meas, ctypes.byref(self._command)):
            raise RuntimeError("rollbot_step failed (the generated code returned an error)")
        accel, status = float(self._command.accel), int(self._command.status)
        self._log(meas, accel, status)
        return Command(accel=accel)

    def report(self) -> dict:
        return {**super().report(), "solver": "exported C (qrqp)", "library": LIBRARY,
                "library_sha256": self.library_sha256}
