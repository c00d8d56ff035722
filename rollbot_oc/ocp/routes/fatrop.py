"""The fatrop route: a structure-exploiting interior point for stage-wise problems."""

from __future__ import annotations

import casadi as ca

from rollbot_oc.errors import ConfigError
from rollbot_oc.ocp.routes.ipopt import NLPRoute

__all__ = ["FatropRoute"]


class FatropRoute(NLPRoute):
    """fatrop on the transcription, where it applies: fixed durations, no global variables, no node slacks.

    The transcription orders ``w`` stage by stage and writes every continuity
    gap as ``x_{k+1} - F(x_k, u_k)``, which is what fatrop's structure
    detection needs; global entries (free durations, variables, node slacks)
    would couple all stages, so those problems are refused with a clear error.
    """

    name = "fatrop"

    def __init__(self, transcription, max_iter: int = 500, tol: float = 1e-8, options: dict | None = None):
        L = transcription.layout
        if L.nt or L.variables or L.node_slacks.stop > L.node_slacks.start:
            raise ConfigError("the fatrop route applies to stage-wise problems: fixed durations, no global "
                              "variables and no soft node constraints; use 'ipopt' or 'sqp'")
        if not ca.has_nlpsol("fatrop"):
            raise ConfigError("the fatrop route needs CasADi's fatrop plugin, which this CasADi lacks")
        self.transcription = tr = transcription
        nlp = {"x": tr.w, "p": tr.par, "f": tr.f, "g": tr.g}
        opts = {"structure_detection": "auto", "equality": (tr.lbg == tr.ubg).tolist(), "expand": True,
                "print_time": False, "debug": False,
                "fatrop": {"print_level": 0, "max_iter": max_iter, "tol": tol, **(options or {})}}
        self.solver = ca.nlpsol("ocp_fatrop", "fatrop", nlp, opts)
