"""Moved: NVIDIA's ZeroMQ transport is conflictbench's own,
:mod:`conflictbench.hosting.zeromq` (kept importable here)."""

from conflictbench.hosting.zeromq import ZmqTransport, answers_ping

Gr00tTransport = ZmqTransport

__all__ = ["Gr00tTransport", "answers_ping"]
