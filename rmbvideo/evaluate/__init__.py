"""Metrics, the paper's baselines (GC20, MG20) and the evaluation table."""
