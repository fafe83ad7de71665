"""A whole campaign on Dask: every flight synchronised once, every segment georeferenced and
orthorectified as a task of its own, the orthos and mosaics as Cloud-Optimized GeoTIFFs, a
STAC catalog over them (docs/campaign.md). The graph and the stamps that make a rerun skip
what is done are `runner`; what each task does on a worker, `tasks`; the maths stays in the
georeferencing stage. Other stages and the commands use only the names below.
"""

from postproc.campaign.cog import check_cog, write_cog
from postproc.campaign.config import (
    CampaignSpec,
    FlightSpec,
    check_name,
    check_unique,
    load_campaign,
)
from postproc.campaign.fingerprint import file_fingerprint, task_key
from postproc.campaign.runner import CampaignRun, Driver, Events, Stage
from postproc.campaign.stac import validate_catalog, write_catalog

__all__ = [
    "CampaignRun", "CampaignSpec", "Driver", "Events", "FlightSpec", "Stage", "check_cog",
    "check_name", "check_unique", "file_fingerprint", "load_campaign", "task_key",
    "validate_catalog", "write_catalog", "write_cog",
]
