"""Deprecated (goes in conflictbench 0.4.0): NVIDIA's ZeroMQ transport moved to conflictbench's own
:mod:`conflictbench.hosting.zeromq` in 0.3; reading a name here warns and gives that module's."""

from conflictbench.core.deprecation import moved_names

__getattr__ = moved_names(
    __name__,
    {
        "Gr00tTransport": "conflictbench.hosting.zeromq:ZmqTransport",
        "ZmqTransport": "conflictbench.hosting.zeromq:ZmqTransport",
        "answers_ping": "conflictbench.hosting.zeromq:answers_ping",
    },
)
