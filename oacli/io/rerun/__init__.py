"""Rerun recordings of the oacli stages.

* :mod:`oacli.io.rerun.writer` -- :class:`~oacli.io.rerun.writer.StageRecording` (one recording, buffered in
  memory, saved atomically), the entity names every stage shares and the view helpers;
* one module per stage with its entities, default layout (blueprint) and ``write_<stage>_recording``:
  :mod:`~oacli.io.rerun.plan`, :mod:`~oacli.io.rerun.smooth`, :mod:`~oacli.io.rerun.excite`,
  :mod:`~oacli.io.rerun.track` (with the tube controller's layers in :mod:`~oacli.io.rerun.tube`),
  :mod:`~oacli.io.rerun.estimate`;
* :mod:`oacli.io.rerun.read` -- reading a recording's values back.
"""
