"""The controller on the robot: the estimator and the NMPC's real-time iteration exported as standalone C.

One description, many uses (``step``): the whole control period is one CasADi Function; the Python
embedded controller (``embedded``) evaluates it in CasADi, the C project (``project``: ``rollbot-oc
export-c``) is generated from it, and the closed loop through C (``library``) drives the compiled
project from the simulator.  The reference the exported controller tracks is planned offline
(``reference``): the C step does not plan.
"""
