"""Campaigns (issue 16): Monte Carlo dry-runs of a mission on randomised scenarios.

* :mod:`executive.campaign.spec` — the campaign file (``schemas/campaign.xsd``) and its
  strict loader;
* :mod:`executive.campaign.route` — the route's geometry and the placement rules;
* :mod:`executive.campaign.sampler` — episode k's scenario, a pure function of
  (campaign seed, k), and its export as a scenario file;
* :mod:`executive.campaign.results` — the results file (JSON lines), merging, summary;
* :mod:`executive.campaign.runner` — running episodes in worker processes;
* :mod:`executive.campaign.cli` — ``walkaround campaign``.
"""
