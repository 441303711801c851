"""Independent measured-robot data for testing ``leadthrough analyze``.

Nothing here imports the project (``control``, ``sim_bridge``, ``drivers``, ``gateway``): the arm
(:mod:`.arm`), the excitation, friction, noise and undeclared effects (:mod:`.generator`) and the
plain least-squares baseline (:mod:`.baseline`) are built from numpy, scipy, pinocchio and
mujoco alone. ``python -m tests.independent.table`` runs the product's CLI on every case.
"""
