"""rollbot_oc: modelling, analysis and control of Rollbot, the single-motor spherical robot.

The package is laid out by layer; a module imports only from its own layer or the ones before it
(``tests/test_layout.py`` checks this and that there is no import circle):

==============  ==========================================================================================
``core``        plumbing: errors and exit codes, checked settings, reproducible arithmetic, fast calls, files,
                progress displays
``model``       parameters, equations of motion, rotations, code generation of CasADi Functions
``view``        text with units, figures and animations (what a person reads and sees)
``ocp``         the optimal-control layer: an OCP on any model, written once, transcribed and solved by a route
``simulation``  the plant, its sensors and the onboard estimation (EKF); the plant calls a controller
                through ``control.protocol``
``analysis``    quasi-stable states, their stability, the design space, the open-loop experiments
``planning``    Rollbot's OCP model and limits, minimum-time legs and orbit entries, plans through gates
``missions``    what a run must achieve (circle, waypoints, gates, open loop) and how it is scored
``control``     the controllers: the protocol, the paper's PID and waypoint layer, the NMPC
``scenarios``   scenario files, the bundled scenarios, seeded random courses, minimum-time bounds
``campaign``    many runs on a cluster (Dask), ``export`` the controller as C, ``robot`` the link to a robot
``app``         the command line ``rollbot-oc`` and the demo report
==============  ==========================================================================================

Older module paths (``rollbot_oc.simulate``, ``rollbot_oc.params``, ``rollbot_oc.problems``, ...) stay
importable: ``MOVED`` maps each to the module that holds its contents now, and an import of an old path
returns that module (the same object, so a name patched through either path is patched for both).
``MOVED_NAMES`` does the same for single names that moved out of a module that stays (``rollbot_oc.ocp``'s
``rollbot_model``, now above the generic optimal-control layer): the module's ``__getattr__`` asks
``moved_name``, which imports the name from where it lives now, when it is first used.
``from rollbot_oc import RollbotParams`` (and the other names in ``EXPORTS``) imports the name's module
on first use, so that ``import rollbot_oc`` stays cheap.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

__version__ = "0.1.0"

# old module path -> the module that holds its contents now
MOVED = {
    "rollbot_oc.errors": "rollbot_oc.core.errors",
    "rollbot_oc.checked": "rollbot_oc.core.checked",
    "rollbot_oc.reproducible": "rollbot_oc.core.reproducible",
    "rollbot_oc.fastcall": "rollbot_oc.core.fastcall",
    "rollbot_oc.outputs": "rollbot_oc.core.outputs",
    "rollbot_oc.progress": "rollbot_oc.core.progress",
    "rollbot_oc.params": "rollbot_oc.model.params",
    "rollbot_oc.dynamics": "rollbot_oc.model.dynamics",
    "rollbot_oc.rotations": "rollbot_oc.model.rotations",
    "rollbot_oc.codegen": "rollbot_oc.model.codegen",
    "rollbot_oc.summary": "rollbot_oc.view.text",
    "rollbot_oc.plots": "rollbot_oc.view.plots",
    "rollbot_oc.animate": "rollbot_oc.view.animate",
    "rollbot_oc.simulate": "rollbot_oc.simulation.plant",
    "rollbot_oc.sensors": "rollbot_oc.simulation.sensors",
    "rollbot_oc.onboard": "rollbot_oc.simulation.onboard",
    "rollbot_oc.estimation": "rollbot_oc.simulation.ekf",
    "rollbot_oc.quasi_stable": "rollbot_oc.analysis.quasi_stable",
    "rollbot_oc.stability": "rollbot_oc.analysis.stability",
    "rollbot_oc.design": "rollbot_oc.analysis.design",
    "rollbot_oc.experiments": "rollbot_oc.analysis.experiments",
    "rollbot_oc.control.ocp": "rollbot_oc.planning.min_time",
    "rollbot_oc.control.plan": "rollbot_oc.planning.plan",
    "rollbot_oc.control.guesses": "rollbot_oc.planning.guesses",
    "rollbot_oc.control.nmpc.gates": "rollbot_oc.planning.gates",
    "rollbot_oc.control.missions": "rollbot_oc.missions",
    "rollbot_oc.problems": "rollbot_oc.scenarios.problem",
    "rollbot_oc.courses": "rollbot_oc.scenarios.courses",
    "rollbot_oc.bounds": "rollbot_oc.scenarios.bounds",
    "rollbot_oc.cli": "rollbot_oc.app.cli",
    "rollbot_oc.report": "rollbot_oc.app.report",
    "rollbot_oc.ocp.constraints": "rollbot_oc.planning.rollbot",
}

# old dotted path of a name in a module that stays -> the module that holds the name now
MOVED_NAMES = {
    "rollbot_oc.ocp.rollbot_model": "rollbot_oc.planning.rollbot",
    "rollbot_oc.ocp.model.rollbot_model": "rollbot_oc.planning.rollbot",
}

# public name -> the module it comes from (``from rollbot_oc import name``)
EXPORTS = {
    "ConfigError": "rollbot_oc.core.errors",
    "RollbotParams": "rollbot_oc.model.params",
    "rest_state": "rollbot_oc.model.dynamics",
    "symbolic_model": "rollbot_oc.model.dynamics",
    "quasi_stable_state": "rollbot_oc.analysis.quasi_stable",
    "quasi_stable_curve": "rollbot_oc.analysis.quasi_stable",
    "RadiusMap": "rollbot_oc.analysis.quasi_stable",
    "stability_curve": "rollbot_oc.analysis.stability",
    "simulate": "rollbot_oc.simulation.plant",
    "Observation": "rollbot_oc.control.protocol",
    "Command": "rollbot_oc.control.protocol",
    "Controller": "rollbot_oc.control.protocol",
    "ControllerBase": "rollbot_oc.control.protocol",
    "OCP": "rollbot_oc.ocp",
    "RestToRest": "rollbot_oc.planning.min_time",
    "OCPSettings": "rollbot_oc.planning.min_time",
    "NMPCSettings": "rollbot_oc.control.nmpc",
    "load_problem": "rollbot_oc.scenarios.problem",
    "run_problem": "rollbot_oc.scenarios.problem",
    "compare": "rollbot_oc.scenarios.problem",
    "load_bundled": "rollbot_oc.scenarios.bundled",
    "random_course": "rollbot_oc.scenarios.courses",
    "run_campaign": "rollbot_oc.campaign",
    "load_campaign_spec": "rollbot_oc.campaign",
}

__all__ = ["__version__", *EXPORTS]


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old module path of ``MOVED`` and loads it as the module that holds its contents now."""

    def find_spec(self, name, path=None, target=None):
        return importlib.util.spec_from_loader(name, self) if name in MOVED else None

    def create_module(self, spec):
        return importlib.import_module(MOVED[spec.name])

    def exec_module(self, module):
        """Nothing to run: the module was imported (and run) under its own name."""


# First in line: an old path must not reach a finder that could still see a stale copy of the old file
# (an editable install of another checkout, a leftover .py from an older version).
if not any(isinstance(finder, _MovedModules) for finder in sys.meta_path):
    sys.meta_path.insert(0, _MovedModules())


def moved_name(module: str, name: str):
    """The value of ``module.name`` where ``name`` moved to (``MOVED_NAMES``), for a module's ``__getattr__``;
    ``AttributeError`` as Python's own if the name never was there."""
    where = MOVED_NAMES.get(f"{module}.{name}")
    if where is None:
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    return getattr(importlib.import_module(where), name)


def __getattr__(name: str):
    if name in EXPORTS:
        value = getattr(importlib.import_module(EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rollbot_oc' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *EXPORTS])
