"""GR00T N1.7 for conflictbench.

The client (:mod:`.client`, loaded by conflictbench through the entry point in :mod:`.plugin`) speaks NVIDIA
Isaac-GR00T's ZeroMQ protocol (:mod:`.protocol`, on conflictbench's ``hosting.zeromq`` transport) and does
GR00T's LIBERO client's processing (:mod:`.processing`); the server (:mod:`.server`, :mod:`.backend`, run with
``conflictbench-serve gr00t`` in the model environment, found through :mod:`.serve`) hosts a LeRobot checkpoint.
:mod:`.protocol` imports nothing of conflictbench, so a server in a model environment (which has no
conflictbench) can share it.
"""
