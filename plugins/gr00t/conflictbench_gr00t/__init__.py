"""GR00T N1.7 for conflictbench.

The client (:mod:`.client`, conflictbench's entry point) speaks NVIDIA Isaac-GR00T's ZeroMQ protocol
(:mod:`.protocol`, on conflictbench's ``hosting.zeromq`` transport) and does GR00T's LIBERO client's processing
(:mod:`.processing`); the server (:mod:`.server`, conflictbench-serving's entry point, and :mod:`.backend`, run with
``conflictbench-serve gr00t`` in the model environment) hosts a LeRobot checkpoint. :mod:`.protocol` imports
nothing of conflictbench, so a server in a model environment (which has no conflictbench) can share it.
"""
