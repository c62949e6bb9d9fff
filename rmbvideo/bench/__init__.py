"""Benchmarks: speed and accuracy measured against references in the same run."""
