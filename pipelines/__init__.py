"""Command lines and the dataset builder."""
