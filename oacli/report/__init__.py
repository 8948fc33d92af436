"""``oacli report``: one self-contained HTML page of a mission, a stage or a campaign folder (``docs/report.md``).

The page is read from the folder's own files (``summary.json``, the MCAPs through :mod:`oacli.io` readers, the PNGs
already drawn), never by running anything again; images and data are inlined, so the file opens offline and can be
sent as it is. Layering: above :mod:`oacli.campaign`, below :mod:`oacli.commands`.
"""
