"""The server half conflictbench's model plugins share (see the README). Imports nothing heavy: each module
is imported where it is needed, in the simulator's environment or in a model environment."""
