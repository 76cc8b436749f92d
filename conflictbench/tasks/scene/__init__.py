"""What a base task's scene holds: facts from its initial states, categories and their affordances,
the words for things, and the task model the operators and the validator read."""
