"""Offline tools (evaluation, benchmarks, demo): they call the same core as the nodes."""
