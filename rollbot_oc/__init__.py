"""rollbot_oc: modelling, analysis and control of Rollbot, the single-motor spherical robot."""

__version__ = "0.1.0"
