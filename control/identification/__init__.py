"""Identification of a robot's dynamic model from measured data, for any serial URDF.

Two ways in, one pipeline:

- **Offline** (``leadthrough analyze``, :mod:`.cli`): measurement files of any robot in, a
  model out; no bus, no cell. Read measurement CSVs or Parquet (:mod:`.datafile`), filter,
  derive velocities and accelerations and decimate (:mod:`.preprocess`), build the
  base-parameter regressor with pinocchio (:mod:`.rigid`), fit rigid body + friction by
  weighted least squares (:mod:`.fit`), validate on held-out trajectories (:mod:`.validate`),
  then look for residual structure and add the physical effect it points to (:mod:`.effects`),
  and write the model file (:mod:`.model`) and a report (:mod:`.report`). :mod:`.analyze`
  ties the stages together (:mod:`.stages`, :mod:`.load`, :mod:`.families`, :mod:`.guard`).
- **On the cell** (``leadthrough identify``, :mod:`.on_cell`): the commissioning run through
  the product. The gateway enters IDENTIFYING, the control process plays the excitation plan
  (:mod:`control.experiments`), the bus is recorded, each experiment segment is exported to
  the measurement format and handed to the offline pipeline above; the velocity steps
  estimate the vendor's inner loop (:mod:`.inner_loop`).
"""
