"""Offline identification of a robot's dynamic model from measured data, for any serial URDF.

Pipeline (``leadthrough analyze``): read measurement CSVs (:mod:`.datafile`), filter, derive
velocities and accelerations and decimate (:mod:`.preprocess`), build the base-parameter
regressor with pinocchio (:mod:`.rigid`), fit rigid body + friction by weighted least squares
(:mod:`.fit`), validate on held-out trajectories (:mod:`.validate`), then look for residual
structure and add the physical effect it points to (:mod:`.effects`), and write the model file
and a report (:mod:`.report`). :mod:`.analyze` ties the stages together, :mod:`.cli` is the
command line.
"""
