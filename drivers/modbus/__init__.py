"""Modbus TCP driver for the cell's pressure and safety I/O module."""
