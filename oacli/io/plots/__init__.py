"""PNG plots written into each stage's run folder (matplotlib, Agg): :mod:`.track`, :mod:`.plan`, :mod:`.excite`,
:mod:`.estimate`; shared helpers in :mod:`.common`."""
