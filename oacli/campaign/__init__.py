"""``oacli campaign``: Monte Carlo missions with dispersions and flight faults, reproducible, on any executor.

:mod:`~oacli.campaign.sampling` draws each run's config, :mod:`~oacli.campaign.jobs` flies one run in a worker,
:mod:`~oacli.campaign.executors` builds the executor, :mod:`~oacli.campaign.driver` runs the campaign with failure
isolation and the append-only :mod:`~oacli.campaign.manifest`, :mod:`~oacli.campaign.aggregate` and
:mod:`~oacli.campaign.outputs` turn the manifest into statistics, plots and recordings.
"""
