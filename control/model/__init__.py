"""Declared models of the paper: rigid-body dynamics, friction eqs. (14)-(17), cylinders."""
