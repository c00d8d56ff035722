"""Campaigns: many independent cases (closed-loop runs, design points, any function), on Dask.

A campaign is a spec (TOML, ``spec``) listing cases of one kind, each with
its own seed and identity (``case``); it runs in this process, on a local
Dask cluster or on an existing one (``execution``), streams its rows to disk
and resumes where it stopped (``store``), and ends with a table
(``results.parquet``), a summary and figures (``summary``, ``figures``).
The kinds: ``closed_loop`` (controllers on random courses), ``design``
(design points, ``design_points``) and ``function`` (a user function).

Examples
--------
>>> from rollbot_oc.campaign import load_campaign_spec, run_campaign      # doctest: +SKIP
>>> result = run_campaign(load_campaign_spec("design"), "out/design", workers=2)
>>> result.summary["success_rate"], result.table.head()
"""

from rollbot_oc.campaign.case import KINDS, Case, CaseKind, Outcome
from rollbot_oc.campaign import closed_loop, design_points, function  # noqa: F401 (they register their kinds)
from rollbot_oc.campaign.run import CampaignResult, run_campaign
from rollbot_oc.campaign.spec import Campaign, bundled_campaigns, campaign_from_dict, load_campaign, load_campaign_spec
from rollbot_oc.campaign.store import RUN_COLUMNS

__all__ = ["Campaign", "Case", "CaseKind", "Outcome", "KINDS", "CampaignResult", "run_campaign", "load_campaign",
           "load_campaign_spec", "campaign_from_dict", "bundled_campaigns", "RUN_COLUMNS"]
