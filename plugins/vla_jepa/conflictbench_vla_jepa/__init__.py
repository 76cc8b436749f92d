"""VLA-JEPA for conflictbench.

The client (:mod:`.client`, loaded by conflictbench through the entry point in :mod:`.plugin`) speaks VLA-JEPA's
websocket protocol (:mod:`.protocol`: starVLA's server on openpi's wire format, read and written with the π
plugin's codec and transport) and does VLA-JEPA's LIBERO client's processing (:mod:`.processing`).
"""
