"""Benchmark scripts (run as ``python benchmarks/NAME.py``) and the seed paper's baselines."""
