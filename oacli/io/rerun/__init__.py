"""Rerun recordings of the oacli stages.

* :mod:`oacli.io.rerun.writer` -- :class:`~oacli.io.rerun.writer.StageRecording` (one recording, buffered in
  memory, saved atomically), with its 3-D layers in :mod:`~oacli.io.rerun.spatial` and the shared names, colours
  and checks in :mod:`~oacli.io.rerun.common`;
* :mod:`oacli.io.rerun.layout` -- view helpers (time series, cameras framed on a path, titles naming the frame)
  and :mod:`oacli.io.rerun.chart` -- static line charts of convergence figures;
* one module per stage with its entities, default layout (blueprint) and ``write_<stage>_recording``:
  :mod:`~oacli.io.rerun.plan`, :mod:`~oacli.io.rerun.smooth`, :mod:`~oacli.io.rerun.excite`,
  :mod:`~oacli.io.rerun.track` (with the tube controller's layers in :mod:`~oacli.io.rerun.tube`),
  :mod:`~oacli.io.rerun.estimate`, and the campaign's :mod:`~oacli.io.rerun.campaign`;
* :mod:`oacli.io.rerun.read` -- reading a recording's values back.

Application ids: one per recording kind (``oacli-plan``, ``oacli-track-mpc``, ``oacli-track-tube``,
``oacli-excite-offline``, ``oacli-excite-rattle``, ...): the viewer keeps one blueprint per application id, so
recordings of different kinds open side by side in one viewer, each in its own layout.
"""
