"""Supervisor, lifecycle, operator commands and the zenoh bus contract shared by all processes."""
