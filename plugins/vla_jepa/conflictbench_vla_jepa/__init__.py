"""VLA-JEPA for conflictbench.

Two halves: the client (:mod:`.client`, loaded by conflictbench through the entry point in :mod:`.plugin`) speaks
VLA-JEPA's websocket protocol (:mod:`.protocol`: starVLA's server on openpi's wire format) and does VLA-JEPA's
LIBERO client's processing (:mod:`.processing`); the server (:mod:`.server`, :mod:`.backend`, run with
``conflictbench-serve vla-jepa`` in the model environment, found through :mod:`.serve`) hosts a LeRobot
checkpoint over the same protocol. This module imports nothing: the model environment has no conflictbench.
"""
