"""LIBERO base tasks, BDDL reading, and the conflict suite."""
