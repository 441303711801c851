"""A stand-in for a zenoh session in unit tests: what a process puts on the bus, kept in order."""

from __future__ import annotations


class RecordingSession:
    """Keeps every ``put`` as (key, payload)."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, bytes]] = []

    def put(self, key: str, payload: bytes) -> None:
        self.puts.append((key, payload))
