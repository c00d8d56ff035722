"""Design sweeps: their progress bar (tqdm) speaks on stderr only when asked or on a terminal."""

import math

from rollbot_oc.analysis.design import sweep
from rollbot_oc.model.params import RollbotParams

PHIS = [math.radians(40), math.radians(50)]


def test_sweep_progress_is_silent_off_a_terminal_unless_asked(capsys):
    quiet = sweep(RollbotParams(), "phi", PHIS, speeds=6)  # pytest's stderr is not a terminal
    assert capsys.readouterr() == ("", "")
    shown = sweep(RollbotParams(), "phi", PHIS, speeds=6, show_progress=True)
    out, err = capsys.readouterr()
    assert out == "" and "sweeping phi" in err and "2/2" in err
    sweep(RollbotParams(), "phi", PHIS, speeds=6, show_progress=False)
    assert capsys.readouterr() == ("", "")
    assert [p.R0_min for p in quiet] == [p.R0_min for p in shown]
    assert quiet[0].R0_min < quiet[1].R0_min  # R0 at rest is R tan(phi)
