"""Deprecated (goes in conflictbench 0.4.0): NVIDIA's ZeroMQ transport moved to conflictbench's own
:mod:`conflictbench.hosting.zeromq` in 0.3; reading a name here warns and gives that module's."""

from conflictbench.core.deprecation import moved_names

MOVED = {
    "Gr00tTransport": "conflictbench.hosting.zeromq:ZmqTransport",
    "ZmqTransport": "conflictbench.hosting.zeromq:ZmqTransport",
    "answers_ping": "conflictbench.hosting.zeromq:answers_ping",
}
__getattr__ = moved_names(__name__, MOVED)
__all__ = ["Gr00tTransport", "answers_ping"]  # noqa: F822 (0.2's exports: a star import warns and works)
