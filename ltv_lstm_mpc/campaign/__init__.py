"""Campaigns: many closed loops over a product of factors, on Dask, resumable.

A campaign spec (TOML, :mod:`ltv_lstm_mpc.campaign.spec`) lists fixed settings and factors
(solver, horizon, L_d, measurement noise, q2 profile, pH-plant mismatch, seed, ...); each
task of their product is one closed loop of the one controller
(:func:`~ltv_lstm_mpc.campaign.task.run_task`) and gives one row of a tidy table. Tasks run
in this process or on Dask (:func:`~ltv_lstm_mpc.campaign.runner.run_campaign`); each
finished task is stored at once under the output folder, keyed by a hash of its settings
and the library version, so a rerun skips it (:mod:`ltv_lstm_mpc.campaign.store`).
:func:`~ltv_lstm_mpc.campaign.report.write_report` writes the markdown summary and plots,
with the (epsilon, beta) statements of :mod:`ltv_lstm_mpc.campaign.statements`.

Dask and pyarrow come with the extra ``campaign``; without them campaigns run serially and
write CSV only.
"""

from __future__ import annotations

from ltv_lstm_mpc.campaign.runner import (
    CampaignError,
    CampaignRun,
    Estimate,
    estimate_campaign,
    run_campaign,
)
from ltv_lstm_mpc.campaign.spec import CampaignSpec, load_spec, parse_spec
from ltv_lstm_mpc.campaign.statements import (
    Statement,
    campaign_statements,
    clopper_pearson_upper,
    loops_needed,
)
from ltv_lstm_mpc.campaign.task import Task, TaskOutcome, execute, run_task

__all__ = [
    "CampaignError",
    "CampaignRun",
    "CampaignSpec",
    "Estimate",
    "Statement",
    "Task",
    "TaskOutcome",
    "campaign_statements",
    "clopper_pearson_upper",
    "estimate_campaign",
    "execute",
    "load_spec",
    "loops_needed",
    "parse_spec",
    "run_campaign",
    "run_task",
]
