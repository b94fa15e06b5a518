"""Monte Carlo campaigns: many independent, seeded runs of one scenario over a few cases (e.g. the
vehicle speeds of seed 002 section 4), spread over local processes or a Dask distributed cluster.

    landing-sim montecarlo gv-marker-ekf --runs 100 --speeds 3 6 12 --workers 2 --out results/mc
    landing-sim montecarlo gv-marker-ekf --runs 1000 --scheduler tcp://host:8786 --out results/mc

A campaign runs a *definition* (`CampaignDefinition`, by scenario name in `CAMPAIGNS`): a picklable
run function `run(task: RunTask) -> dict | RunOutput`, the cases it knows, and hooks that aggregate
the finished runs into summary.json's "filters" and draw plots. Its *settings* (`CampaignSettings`:
scenario, cases, runs per case, base seed, `--set` overrides) are saved in `<out>/campaign.json`.

Guarantees:
- Seeds: run i of case c gets `run_seed(base_seed, c, i)`, whatever the executor or completion
  order; records are read back in (case, index) order, so summaries are identical too.
- Records: the main process writes `<out>/runs/<case>/<index>.json` (and `.npz` of the run's
  arrays) atomically as each run finishes; a run that raises, or whose worker dies, is recorded
  as failed with the reason, and the campaign goes on.
- Resume: the same command again skips every run that has a record (failed ones too, unless
  `retry_failed`); an output directory holding a campaign with other settings is an error, untouched.
- Executors: a `spawn` process pool, an existing Dask cluster (`scheduler`), or `workers=0`: every
  run in this process, one after the other (for a debugger).

Modules: settings (seeds, tasks), records (run outputs and records), definition (campaign
definitions and checked settings), aggregate (statistics), executors, campaign (run_campaign).
"""

from diagrams.montecarlo.aggregate import aggregate_fields, default_aggregate
from diagrams.montecarlo.campaign import run_campaign, write_summary
from diagrams.montecarlo.definition import (
    CAMPAIGNS, CampaignDefinition, campaign_definition, campaign_settings, parse_number_case,
)
from diagrams.montecarlo.executors import DEFAULT_CONNECT_TIMEOUT_S, default_workers
from diagrams.montecarlo.records import RunOutput, RunRecord, read_records
from diagrams.montecarlo.settings import FORMAT, SEED_SCHEME, CampaignSettings, RunTask, run_seed

__all__ = [
    "CAMPAIGNS", "DEFAULT_CONNECT_TIMEOUT_S", "FORMAT", "SEED_SCHEME", "CampaignDefinition", "CampaignSettings",
    "RunOutput", "RunRecord", "RunTask", "aggregate_fields", "campaign_definition", "campaign_settings",
    "default_aggregate", "default_workers", "parse_number_case", "read_records", "run_campaign", "run_seed",
    "write_summary",
]
