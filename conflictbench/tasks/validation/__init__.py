"""The validator: every rule a conflict case must meet, re-checked from data (no simulator)."""
