"""π0, π0-FAST and π0.5 for conflictbench.

Two halves: the client (:mod:`.client`, conflictbench's entry point) speaks openpi's protocol (:mod:`.protocol`, on
conflictbench's ``hosting.openpi`` transport) and does openpi's LIBERO client's processing (:mod:`.processing`); the
server (:mod:`.server`, conflictbench-serving's entry point, and :mod:`.backend`, run with ``conflictbench-serve pi0``
in the model environment) hosts a LeRobot checkpoint over the same protocol.
This module imports nothing: the model environment has no conflictbench.
"""
