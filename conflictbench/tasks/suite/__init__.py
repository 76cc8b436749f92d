"""The conflict suite: building it from the operators, its file, and the review it ships with."""
