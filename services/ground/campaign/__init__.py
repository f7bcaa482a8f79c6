"""Monte Carlo campaigns (``ddvi campaign``): the campaign file and its dispersions
(``dispersions``), one run on a worker (``run``), the result table (``store``), the command on a
Dask cluster (``command``), and the report with its figures (``report``, ``figures``).
docs/campaigns.md."""

from services.ground.campaign.command import (
    add_campaign_arguments,
    campaign_command,
    load_campaign,
)

__all__ = ["add_campaign_arguments", "campaign_command", "load_campaign"]
