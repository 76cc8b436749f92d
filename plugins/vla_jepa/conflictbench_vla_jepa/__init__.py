"""VLA-JEPA for conflictbench.

Two halves: the client (:mod:`.client`, conflictbench's entry point) speaks VLA-JEPA's websocket protocol
(:mod:`.protocol`: starVLA's server on openpi's wire format) and does VLA-JEPA's LIBERO client's processing
(:mod:`.processing`); the server (:mod:`.server`, conflictbench-serving's entry point, and :mod:`.backend`, run with
``conflictbench-serve vla-jepa`` in the model environment) hosts a LeRobot checkpoint over the same protocol. This
module imports nothing: the model environment has no conflictbench.
"""
