"""The simulation core, between the controllers and the studies.

* :mod:`hydroarm.sim.plant_protocol`: the plant protocol every true plant follows (the fixed-base arm,
  the vehicle with its arm), with sensing and fault handling left to the runner;
* :mod:`hydroarm.sim.experiment`: :class:`~hydroarm.sim.experiment.ExperimentConfig`, the one
  experiment builder and :func:`~hydroarm.sim.experiment.run_experiment`;
* :mod:`hydroarm.sim.runner`: the one closed loop (:func:`~hydroarm.sim.runner.run_closed_loop`)
  and its record, :class:`~hydroarm.sim.runner.Trajectory`, with the tracking metrics;
* :mod:`hydroarm.sim.files`: files written whole or not at all.

The studies (reproduce, sweep, tune, the vehicle study), the Gymnasium envs and the CLI build
on this layer; it imports the controllers and the model, never a study.
"""
