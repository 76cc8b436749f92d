"""LIBERO's base tasks: the benchmark registry, BDDL problems and fixed initial states (no simulator)."""
