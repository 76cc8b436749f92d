"""``conflictbench doctor``: is this machine's simulator the reference one?

Golden scripted-expert episodes, made on each pinned stack by ``scripts/make_goldens.py`` and shipped in
``goldens/<stack key>/``, are replayed here with and without cameras: their end-effector paths and success steps
(physics) and frames of both cameras (rendering) are compared with the goldens'. Plays no run's episode.
"""
