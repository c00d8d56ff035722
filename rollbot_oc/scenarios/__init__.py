"""Scenarios: scenario files and running them (``problem``), the bundled scenarios (``bundled``), seeded random
courses (``courses``) and the minimum-time bound of a course (``bounds``).

The bundled scenarios' functions are re-exported here (``from rollbot_oc.scenarios import load_bundled``).
"""

from rollbot_oc.scenarios.bundled import (  # noqa: F401
    bundled_names, bundled_table, bundled_text, file_or_bundled, list_bundled, load_bundled, load_scenario,
)

__all__ = ["bundled_names", "bundled_text", "bundled_table", "list_bundled", "load_bundled", "file_or_bundled",
           "load_scenario"]
