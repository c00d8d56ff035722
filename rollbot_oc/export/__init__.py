"""The controller on the robot: the NMPC's own control step exported as standalone C, and its replay.

One step, the same everywhere: the C project (``project``: ``rollbot-oc export-c``) holds the C the Python NMPC
compiles from its control period's three Functions (``step_library``; ``control.nmpc.period``, ``control.nmpc.source``)
and a replay of a closed-loop run of the NMPC recorded at the step's boundary (``replay``: what the board receives
from the host's supervisor and what it gives), checked on the host (``make check``) and on a Cortex-M7 under QEMU
(``firmware``: ``make qemu-check``).  The supervisor and its reference windows stay on the host.
"""
