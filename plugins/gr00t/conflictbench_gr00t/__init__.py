"""GR00T N1.7 for conflictbench.

The client (:mod:`.client`, loaded by conflictbench through the entry point in :mod:`.plugin`) speaks NVIDIA
Isaac-GR00T's ZeroMQ protocol (:mod:`.protocol`, :mod:`.transport`) and does GR00T's LIBERO client's
processing (:mod:`.processing`). :mod:`.protocol` imports nothing of conflictbench, so a server in a model
environment (which has no conflictbench) can share it.
"""
