"""``oacli mission``: the three-segment on-orbit assembly mission of [Doerr2021] Fig. 1 and [ReSWARM2023] §4.7, §6.3.1.

A → B with the model known, B → C with the grasped payload uncertain (excitation, tube MPC, estimation), C → A with
the learned model, plus the [Doerr2021] Fig. 3(d) baselines. :mod:`oacli.mission.layout` names the folders,
:mod:`oacli.mission.configs` derives each stage's config from the mission config, :mod:`oacli.mission.run` runs
the stages in order (resuming and rerunning from a stage), :mod:`oacli.mission.compare` builds the baseline table.
"""
