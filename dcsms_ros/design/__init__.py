"""Controller design on the model of the loop as it runs (tuning)."""
