"""Write docs/nmpc_modes.md from the NMPC's mode tables (rollbot_oc.control.nmpc.modes.modes_page)."""

from pathlib import Path

from rollbot_oc.control.nmpc.modes import modes_page

if __name__ == "__main__":
    (Path(__file__).parent / "nmpc_modes.md").write_text(modes_page())
