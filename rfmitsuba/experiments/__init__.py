"""Experiments: the methods registry and job runner, compare, reproduce, demo, benchmarks, reports."""
